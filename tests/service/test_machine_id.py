"""One name per machine: recordings and telemetry topics name it the same way."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from compd.errors import ConfigFileError
from compd.service.config.loading import load_config

ROOT = Path(__file__).parents[2]


def write(tmp_path: Path, **changes: object) -> Path:
    doc = yaml.safe_load((ROOT / "config" / "simulated.yaml").read_text())
    doc["model"] = str(ROOT / "config" / "simulated_model.yaml")
    doc.update(changes)
    path = tmp_path / "compd.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def test_telemetry_takes_the_machine_id_from_the_top(tmp_path: Path) -> None:
    config = load_config(write(tmp_path, machine_id="mill-7", telemetry={"host": "127.0.0.1"}))
    assert config.doc.telemetry is not None and config.doc.telemetry.machine_id == "mill-7"


def test_two_different_names_for_one_machine_are_refused(tmp_path: Path) -> None:
    path = write(tmp_path, machine_id="mill-7", telemetry={"machine_id": "mill-8"})
    with pytest.raises(ConfigFileError, match="differs from machine_id 'mill-7'"):
        load_config(path)


def test_telemetry_without_any_machine_id_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ConfigFileError, match=r"telemetry\.machine_id"):
        load_config(write(tmp_path, telemetry={"host": "127.0.0.1"}))
