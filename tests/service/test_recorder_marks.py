"""What a recording says about itself: its machine in its name, its run, its columns' units, tidy numbers."""

from __future__ import annotations

from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from compd.files.data import load_data
from compd.service.recording.parquet import ParquetRecorder
from compd.service.recording.recorder import Recorder

T0_S = 1_795_428_900.0  # 2026-11-23T10:15:00Z
LIMITS = {"max_file_bytes": 1 << 30, "max_file_age_s": 60.0, "max_total_bytes": 1 << 32}


def test_files_are_named_by_machine_and_marked_with_their_run(tmp_path: Path) -> None:
    """Each file names its machine, its run, the file before it, why it started and the gap since."""
    with Recorder(tmp_path, metadata={"machine_id": "mill-a"}, **LIMITS) as rec:  # type: ignore[arg-type]
        rec.set_model("m1", "1" * 64)
        for k in range(90):  # 1 Hz; rotated by age at 60 s
            if k == 75:
                rec.set_model("m2", "2" * 64)
            rec.record({"x": float(k)}, at_s=T0_S + k)
        rec.record({"x": 90.0}, at_s=T0_S + 50)  # the clock set back
    names = sorted(path.name for path in tmp_path.iterdir())
    assert names == [
        "compd-mill-a-20261123T101500Z.csv",
        "compd-mill-a-20261123T101550Z.csv",
        "compd-mill-a-20261123T101600Z.csv",
        "compd-mill-a-20261123T101615Z.csv",
    ]
    marks = [load_data(tmp_path / name).metadata for name in names if name != names[1]]
    marks.insert(1, _comments(tmp_path / names[1]))  # one row: the loader needs two
    by_start = sorted(marks, key=lambda m: int(m["run_file"]))
    assert len({m["run_id"] for m in marks}) == 1
    assert [m["run_reason"] for m in by_start] == ["start", "rotated", "model", "clock"]
    assert [m.get("run_previous") for m in by_start] == [
        None,
        "compd-mill-a-20261123T101500Z.csv",
        "compd-mill-a-20261123T101600Z.csv",
        "compd-mill-a-20261123T101615Z.csv",
    ]
    assert [m.get("run_gap_s") for m in by_start] == [None, "1.0", "1.0", "-39.0"]


def test_a_new_recorder_is_a_new_run(tmp_path: Path) -> None:
    """Each recorder (each daemon start) has a run id of its own."""
    ids = set()
    for start_s in (T0_S, T0_S + 10):
        with Recorder(tmp_path, **LIMITS) as rec:  # type: ignore[arg-type]
            rec.record({"x": 1.0}, at_s=start_s)
            rec.record({"x": 2.0}, at_s=start_s + 1)
    for path in tmp_path.iterdir():
        ids.add(load_data(path).metadata["run_id"])
    assert len(ids) == 2


def test_numbers_are_written_without_binary_noise(tmp_path: Path) -> None:
    """2115 counts x 0.01 is written 21.15, not 21.150000000000002; -0.0 as 0."""
    with Recorder(tmp_path, **LIMITS) as rec:  # type: ignore[arg-type]
        for k in range(2):
            rec.record(
                {"T_degC": 2115 * 0.01, "z_um": -0.0, "sum": 0.1 + 0.2, "status": 3}, at_s=T0_S + k
            )
    (path,) = tmp_path.iterdir()
    row = path.read_text().splitlines()[-1]
    assert row == "2026-11-23T10:15:01.000+00:00,21.15,0,0.3,3"


def test_parquet_stores_whole_numbers_as_integers_and_each_columns_unit(tmp_path: Path) -> None:
    """Status word, heartbeat and health are int64; other numbers tidy float64; the footer names units."""
    units = {"T_degC": "degC", "status": "bits", "heartbeat": "count"}.get
    with ParquetRecorder(tmp_path, flush_every_rows=5, **LIMITS) as rec:  # type: ignore[arg-type]
        rec.run.units = units
        for k in range(10):
            row = {"T_degC": 2115 * 0.01, "health.T_degC": 0, "status": 3, "heartbeat": k}
            rec.record(row, at_s=T0_S + k)
    (path,) = tmp_path.iterdir()
    table = pq.read_table(path)
    schema = table.schema
    assert [schema.field(n).type for n in ("health.T_degC", "status", "heartbeat")] == [
        pa.int64()
    ] * 3
    assert table["T_degC"][0].as_py() == 21.15
    assert table["status"].to_pylist() == [3] * 10
    metadata = {k.decode(): v.decode() for k, v in schema.metadata.items()}
    assert {k: v for k, v in metadata.items() if k.startswith("unit.")} == {
        "unit.T_degC": "degC",
        "unit.status": "bits",
        "unit.heartbeat": "count",
    }


def _comments(path: Path) -> dict[str, str]:
    """A CSV recording's ``# key: value`` lines."""
    lines = [line[2:] for line in path.read_text().splitlines() if line.startswith("# ")]
    return dict(line.split(": ", 1) for line in lines)
