"""`compd record`: a calibration run recorded from the simulated machine is what `compd fit` reads."""

from __future__ import annotations

import json
import re
from pathlib import Path

import yaml

from compd.cli import main
from compd.cli.recording import FILE_BYTES, recordings
from compd.files.data import MAX_FILE_BYTES
from compd.files.yamlplace import resolve_path
from tests.clirun import compd

from ..drivers.modbus_server import free_port
from ..service.daemon_setup import short_socket

INPUTS = "T_spindle_degC,T_headstock_degC,T_column_front_degC,T_ambient_degC"


def record_config(directory: Path) -> Path:
    """The bundled logger config (record.yaml) on a free port, its state under ``directory``."""
    doc = yaml.safe_load(resolve_path("bundled:record.yaml", Path(".")).read_text())
    doc["drivers"]["plc"]["settings"]["port"] = free_port()
    doc["state"] = {"directory": str(directory / "state")}
    doc["control_socket"] = str(short_socket())
    path = directory / "record.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def test_a_recorded_calibration_run_fits(tmp_path):
    """24 h recorded on virtual time: one file, whose probe column compd fit identifies a model from."""
    config = record_config(tmp_path)
    out = compd("record", "--config", config, "--time-scale", "max", "--hours", 24,
                "--out", tmp_path / "calib", "--log-format", "json")  # fmt: skip
    files = recordings(tmp_path / "calib")
    assert len(files) == 1
    assert "recorded 8641 ticks (24.00 h at 10 s)" in out
    # The README's walk-through: the four temperatures (95.4 %), not every signal (93.5 %).
    hint = f"compd fit --data {files[0]} --output disp_z_um --inputs {INPUTS} --out"
    assert hint in " ".join(out.split())  # (a long path wraps the line at 200 columns)
    model = tmp_path / "base.yaml"
    compd("fit", "--data", files[0], "--output", "disp_z_um", "--inputs", INPUTS, "--out", model)
    summary = json.loads(compd("compare", model, files[0], "--json"))
    assert summary["outputs"]["disp_z_um"]["fit_percent"] > 95


def test_a_short_recording_says_its_length_in_seconds(tmp_path):
    """A run of a minute is "(N s at 10 s)" (not "0.00 h"); lengths read as s, min or h."""
    from compd.cli.terminal import duration_text

    config = record_config(tmp_path)
    out = compd("record", "--config", config, "--time-scale", "max", "--hours", 0.02,
                "--out", tmp_path / "calib", "--log-format", "json")  # fmt: skip
    found = re.search(r"recorded (\d+) ticks \((\d+) s at 10 s\)", out)
    assert found is not None, out
    assert int(found[2]) == 10 * int(found[1])
    assert [duration_text(s) for s in (13, 750, 86_410)] == ["13 s", "12.5 min", "24.00 h"]


def test_record_wants_a_fresh_directory(tmp_path, capsys):
    """A directory that already holds recordings is refused: fit would not know which run is which."""
    (tmp_path / "calib").mkdir()
    (tmp_path / "calib" / "compd-20261124T000000Z.csv").write_text("timestamp,a\n")
    config = record_config(tmp_path)
    assert main(["record", "--config", str(config), "--out", str(tmp_path / "calib")]) == 2
    assert "already holds recordings" in capsys.readouterr().err


def test_virtual_time_is_refused_for_a_real_machine(tmp_path, capsys):
    """--time-scale max needs a simulated machine."""
    out = str(tmp_path / "rec")
    assert (
        main(["record", "--config", "bundled:replay.yaml", "--time-scale", "max", "--out", out])
        == 2
    )
    assert "only for a simulated machine" in capsys.readouterr().err


def test_a_recording_file_stays_readable_by_fit():
    """Files rotate below the size compd fit reads, so every file of a long recording fits as it is."""
    assert FILE_BYTES < MAX_FILE_BYTES
