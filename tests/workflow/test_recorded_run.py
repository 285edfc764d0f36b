"""A day recorded by the daemon in hourly Parquet files fits as one run: the same model as the joined file.

docs/fleet.md recommends hourly Parquet files; the recorder rotates them, but
the machine ran on. Fitted as separate experiments, each file starts from
rest with its own input references (-75 % where the run fits 97 %). Here the
real recorder records the simulated machine's 24 h calibration run (the
twin behind a simulated PLC, on virtual time) through ``compd run``, and
``compd fit`` and ``compare`` on the folder must give what they give on the
same rows in one file.
"""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import yaml

from compd.cli import main
from compd.files.yamlplace import resolve_path
from tests.clirun import compd

from ..drivers.modbus_server import free_port
from ..service.daemon_setup import short_socket

INPUTS = "T_spindle_degC,T_headstock_degC,T_column_front_degC,T_ambient_degC"


@pytest.fixture(scope="module")
def day(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """24 h of the bundled logger config (record.yaml) recorded as mill-a in hourly Parquet files."""
    directory = tmp_path_factory.mktemp("day")
    doc = yaml.safe_load(resolve_path("bundled:record.yaml", Path(".")).read_text())
    doc["machine_id"] = "mill-a"
    doc["drivers"]["plc"]["settings"]["port"] = free_port()
    doc["state"] = {"directory": str(directory / "state")}
    doc["control_socket"] = str(short_socket())
    doc["recorder"] = {
        "directory": str(directory / "records"),
        "format": "parquet",
        "max_file_age_s": 3600,
    }
    doc["simulation"]["stop_at_end"] = True
    config = directory / "record.yaml"
    config.write_text(yaml.safe_dump(doc, sort_keys=False))
    compd("run", "--config", config, "--time-scale", "max", "--log-level", "warning")
    return directory


def _fit_percent(data: Path, model: Path) -> float:
    compd("fit", "--data", data, "--output", "disp_z_um", "--inputs", INPUTS, "--out", model)
    return float(yaml.safe_load(model.read_text())["provenance"]["fit_percent"]["disp_z_um"])


def test_hourly_files_of_one_day_fit_as_the_joined_file(day: Path) -> None:
    """fit on the folder of 24 hourly files gives the joined file's model, fit % to 0.1."""
    files = sorted((day / "records").glob("compd-*.parquet"))
    assert len(files) >= 24
    joined = day / "joined.parquet"
    pq.write_table(pa.concat_tables([pq.read_table(f) for f in files]), joined)
    one_file = _fit_percent(joined, day / "joined.yaml")
    folder = _fit_percent(day / "records", day / "folder.yaml")
    assert one_file > 95.0
    assert folder == pytest.approx(one_file, abs=0.1)
    compared = json.loads(compd("compare", day / "joined.yaml", day / "records", "--json"))
    assert "experiments" not in compared  # one run: one record
    assert compared["outputs"]["disp_z_um"]["fit_percent"] == pytest.approx(one_file, abs=0.1)


def test_the_recorded_files_carry_integers_and_units(day: Path) -> None:
    """Files named by the machine; status word, heartbeat and health integers; units in the footer."""
    first = sorted((day / "records").glob("compd-mill-a-*.parquet"))[0]
    schema = pq.read_schema(first)
    assert schema.field("status").type == schema.field("heartbeat").type == pa.int64()
    assert schema.field("health.T_spindle_degC").type == pa.int64()
    metadata = {k.decode(): v.decode() for k, v in (schema.metadata or {}).items()}
    assert metadata["unit.T_spindle_degC"] == "degC" and metadata["unit.disp_z_um"] == "um"
    assert metadata["machine_id"] == "mill-a" and metadata["run_reason"] == "start"


def test_the_commands_say_what_they_joined(day: Path) -> None:
    """A note says how many files made how many runs of how long, from which machine."""
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        code = main(["fit", "--data", str(day / "records"), "--output", "disp_z_um",
                     "--inputs", INPUTS, "--method", "mlr", "--out", str(day / "mlr.yaml")])  # fmt: skip
    assert code == 0, err.getvalue()
    assert "note: 24 files, 1 run of 24.0 h from mill-a" in err.getvalue()
