"""The recorder's Parquet files from a real service run are what ``compd fit --data DIR`` reads."""

from __future__ import annotations

from pathlib import Path

import pyarrow.parquet as pq

from compd import __version__
from compd.files.experiments import load_experiments
from tests.acceptance.conftest import machine_doc, write_config
from tests.clirun import compd


def test_parquet_recordings_of_a_service_run_fit_as_one_run(
    calibrated_model: Path, short_dir: Path
) -> None:
    """An hour on the simulated machine, files rotated every 20 min: each names the machine, the run fits."""
    doc = machine_doc(
        short_dir,
        calibrated_model,
        simulation={"scenario": "production", "hours": 2},
        machine_id="press-07",
    )
    records = short_dir / "records"
    doc["recorder"] = {
        "enabled": True,
        "directory": str(records),
        "format": "parquet",
        "max_file_age_s": 1200,
    }
    config = write_config(short_dir, doc)
    compd("run", "--config", config.path, "--time-scale", "max", "--duration-s", 3600,
          "--log-format", "json")  # fmt: skip
    files = sorted(records.glob("compd-*.parquet"))
    assert len(files) >= 2, sorted(records.iterdir())
    assert not list(records.glob("*.tmp"))
    for path in files:
        metadata = pq.ParquetFile(path).schema_arrow.metadata
        assert metadata[b"machine_id"] == b"press-07"
        assert metadata[b"compd_version"] == __version__.encode()
        assert metadata[b"model"] == b"twin-z" and len(metadata[b"model_sha256"]) == 64
        assert metadata[b"config"] == str(config.path).encode()
    # The run's last tick may open a file of one row as it ends: left out, with a note.
    whole = [str(p) for p in files if pq.ParquetFile(p).metadata.num_rows >= 2]
    (run,) = load_experiments([records])  # one run: its files joined into one record
    assert list(run.files) == whole and len(whole) >= 2
    assert run.metadata["machine_id"] == "press-07"
    assert len(run) >= 3500  # an hour at 1 s, a flush or so short
    experiments = load_experiments([records], joining="per-file")
    assert [e.path for e in experiments] == whole
    model = short_dir / "refit.yaml"
    fit = [
        "fit", "--data", records, "--output", "model.disp_z_um",
        "--inputs", "T_spindle_degC,T_headstock_degC,T_column_front_degC,T_ambient_degC",
    ]  # fmt: skip
    compd(*fit, "--out", model)
    assert "experiments (files)" not in model.read_text()
    compared = compd("compare", model, records, "--output", "model.disp_z_um")
    assert "pooled over" not in compared
    per_file = short_dir / "per-file.yaml"
    out = compd(*fit, "--experiments", "per-file", "--out", per_file)
    assert f"leave one of {min(len(whole), 6)} experiments (files) out" in out
    compared = compd("compare", model, records, "--experiments", "per-file")
    assert "pooled over" in compared
