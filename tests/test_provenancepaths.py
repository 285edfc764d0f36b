"""Provenance paths are relative to the model file's folder (or ``bundled:NAME``), in the bundled models too."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from compd.files.modelschema import CalibrationDoc, ExtensionDoc, ProvenanceDoc
from compd.files.provenancepaths import portable_command, portable_path, portable_provenance

ROOT = Path(__file__).parents[1]
BUNDLED = ROOT / "config"
EXAMPLE = BUNDLED / "example_spectrum.csv"
#: The start of an absolute path on a build machine: a checkout, a home, a temporary folder.
ABSOLUTE = re.compile(r"(?<![\w.])(/work|/home|/tmp|/root|/Users|/var|/opt|/srv|[A-Z]:\\)")


def bundled_models() -> list[Path]:
    return sorted(p for p in BUNDLED.glob("*.yaml") if "compd.model/" in p.read_text())


@pytest.mark.parametrize("model", bundled_models(), ids=lambda p: p.name)
def test_no_bundled_model_records_an_absolute_path(model: Path) -> None:
    """The examples ship in the wheel: their provenance names no folder of the machine they were fitted on."""
    provenance = yaml.safe_load(model.read_text()).get("provenance", {})
    text = yaml.safe_dump(provenance)
    assert not ABSOLUTE.search(text), f"{model.name}: {ABSOLUTE.search(text)}"


def fit(cwd: Path, data: str, out: str) -> dict[str, object]:
    argv = ["fit", "--data", data, "--output", "disp_z_um", "--inputs", "T*", "--method", "arx",
            "--order", "1", "--out", out]  # fmt: skip
    done = subprocess.run(
        [sys.executable, "-m", "compd.cli", *argv], cwd=cwd, capture_output=True, text=True,
        timeout=300,
    )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    model = Path(out) if Path(out).is_absolute() else cwd / out
    return yaml.safe_load(model.read_text())["provenance"]


def test_fit_of_data_beside_the_model_records_its_name(tmp_path: Path) -> None:
    """Run from elsewhere with absolute paths, as the bundled model was: the record reads from the model's folder."""
    shutil.copy(EXAMPLE, tmp_path / "calib.csv")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    provenance = fit(elsewhere, str(tmp_path / "calib.csv"), str(tmp_path / "model.yaml"))
    assert provenance["data"] == "calib.csv"
    assert provenance["calibration"]["data"] == "calib.csv"
    assert "--data calib.csv" in provenance["command"]
    assert "--out model.yaml" in provenance["command"]
    assert str(tmp_path) not in yaml.safe_dump(provenance)


def test_fit_of_data_in_a_sibling_folder_records_the_way_there(tmp_path: Path) -> None:
    """``data/`` beside ``models/``, run from their parent with relative paths: ``../data/...``."""
    (tmp_path / "data").mkdir()
    (tmp_path / "models").mkdir()
    shutil.copy(EXAMPLE, tmp_path / "data" / "calib.csv")
    provenance = fit(tmp_path, "data/calib.csv", "models/m.yaml")
    assert provenance["data"] == "../data/calib.csv"
    assert "--data ../data/calib.csv" in provenance["command"]
    assert "--out m.yaml" in provenance["command"]


def test_fit_of_bundled_data_records_the_bundled_name(tmp_path: Path) -> None:
    """``bundled:NAME`` is read as data and recorded as such: it resolves from any install."""
    provenance = fit(tmp_path, "bundled:example_spectrum.csv", "m.yaml")
    assert provenance["data"] == "bundled:example_spectrum.csv"
    assert "--data bundled:example_spectrum.csv" in provenance["command"]


def test_files_in_another_tree_stay_absolute(tmp_path: Path) -> None:
    """A share elsewhere: ``../../../mnt/...`` would be no more portable than the absolute path."""
    assert portable_path("/mnt/share/calib.csv", tmp_path) == "/mnt/share/calib.csv"
    assert portable_path("Horejs 2010, eq. 1", tmp_path) == "Horejs 2010, eq. 1"  # a description
    assert portable_command("hand-written 'example", tmp_path) == "hand-written 'example"


def test_a_derived_model_moves_its_parents_entries_to_its_own_folder(tmp_path: Path) -> None:
    """extend/update/residual: the parent's entries were relative to its folder, the new ones to the working dir."""
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    (tmp_path / "a" / "calib.csv").write_text("x")
    (tmp_path / "b" / "extra.csv").write_text("x")
    parent = ProvenanceDoc(
        data="calib.csv",
        command="compd fit --data calib.csv --out parent.yaml",
        calibration=CalibrationDoc(data="calib.csv", samples=1, sample_time_s=1.0),
    )
    child = parent.model_copy(
        update={
            "extensions": [
                ExtensionDoc(parent_sha256="0" * 64, data=str(tmp_path / "b" / "extra.csv"),
                             effect_signal="T_x_degC"),
            ],
        }
    )  # fmt: skip
    moved = portable_provenance(child, tmp_path / "b", parent=parent, parent_dir=tmp_path / "a")
    assert moved.data == "../a/calib.csv"
    assert moved.calibration is not None and moved.calibration.data == "../a/calib.csv"
    assert moved.extensions[0].data == "extra.csv"
    assert moved.command == "compd fit --data ../a/calib.csv --out parent.yaml"
