"""One recorded run across rotated files: which files the toolkit joins into one experiment, and which not."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose

from compd.files.experiments import load_experiments
from compd.service.recording.recorder import Recorder
from tests.clirun import compd

T0_S = 1_795_428_900.0  # 2026-11-23T10:15:00Z
TS_S = 10.0
FILE_S = 600.0  # a file every 10 min: 60 rows


def value(k: int) -> float:
    return 20.0 + 0.01 * k


def make(directory: Path, machine: str | None = "mill-a", **units: str) -> Recorder:
    """A CSV recorder rotating every FILE_S, as a daemon with ``machine_id: machine`` makes it
    (``units``: each column's unit, as the config's signals give them)."""
    metadata = {"machine_id": machine} if machine else {}
    metadata |= {f"unit.{column}": unit for column, unit in units.items()}
    return Recorder(
        directory,
        max_file_bytes=1 << 30,
        max_file_age_s=FILE_S,
        max_total_bytes=1 << 32,
        metadata=metadata,
    )


def write(recorder: Recorder, ticks: range, *, gap_after: int | None = None, gap_s: float = 0.0):
    """Rows of ticks ``ticks`` every TS_S, ``gap_s`` more after tick ``gap_after``."""
    for k in ticks:
        late_s = gap_s if gap_after is not None and k > gap_after else 0.0
        recorder.record({"T_degC": value(k), "disp_um": -0.5 * k}, at_s=T0_S + k * TS_S + late_s)


def recorded(directory: Path) -> list[Path]:
    return sorted(directory.glob("compd-*.csv"))


def test_a_run_rotated_into_files_is_one_experiment_of_all_its_rows(tmp_path: Path) -> None:
    """Four files of one recorded run load as one experiment, its rows in order, and a note says so."""
    with make(tmp_path) as rec:
        write(rec, range(240))
    assert len(recorded(tmp_path)) == 4
    (data,) = load_experiments([tmp_path])
    assert len(data) == 240 and data.sample_time_s == TS_S
    assert_allclose(data.column("T_degC"), [value(k) for k in range(240)])
    assert data.files == tuple(str(p) for p in recorded(tmp_path))
    assert "4 files, 1 run of 40.0 min from mill-a" in data.notes


def test_per_file_keeps_each_file_of_a_run_its_own_experiment(tmp_path: Path) -> None:
    """--experiments per-file overrides the run: every file its own experiment, as before runs."""
    with make(tmp_path) as rec:
        write(rec, range(240))
    experiments = load_experiments([tmp_path], joining="per-file")
    assert [len(e) for e in experiments] == [60, 60, 60, 60]


def test_files_of_different_machines_are_never_joined(tmp_path: Path) -> None:
    """A file naming another machine does not continue a run, not even when asked to join by time."""
    with make(tmp_path) as rec:
        write(rec, range(120))
    second = recorded(tmp_path)[1]
    second.write_text(second.read_text().replace("# machine_id: mill-a", "# machine_id: mill-b"))
    for joining in ("per-run", "contiguous"):
        experiments = load_experiments([tmp_path], joining=joining)  # type: ignore[arg-type]
        assert [len(e) for e in experiments] == [60, 60]
        assert any("another machine (mill-a and mill-b)" in n for n in experiments[0].notes)


def test_files_that_record_a_column_in_different_units_are_never_joined(tmp_path: Path) -> None:
    """A file recording T_degC in degF (the config's unit changed between files) does not continue
    one recording it in degC: joined, its values would be read in the first file's unit."""
    with make(tmp_path, T_degC="degC") as rec:
        write(rec, range(120))
    second = recorded(tmp_path)[1]
    second.write_text(second.read_text().replace("# unit.T_degC: degC", "# unit.T_degC: degF"))
    for joining in ("per-run", "contiguous"):
        experiments = load_experiments([tmp_path], joining=joining)  # type: ignore[arg-type]
        assert [len(e) for e in experiments] == [60, 60]
        assert any(
            "T_degC is recorded in degC in one and in degF" in n for n in experiments[0].notes
        )


def test_a_gap_beyond_max_gap_splits_a_run_and_a_shorter_one_is_interpolated(
    tmp_path: Path,
) -> None:
    """A 5 min gap between two files of a run splits it at --max-gap-s 60 and is filled at 600."""
    with make(tmp_path) as rec:
        write(rec, range(120), gap_after=59, gap_s=300.0)
    split = load_experiments([tmp_path])
    assert [len(e) for e in split] == [60, 60]
    assert any(
        "a gap of 5.0 min (30 missing samples), longer than --max-gap-s 60" in n
        for n in split[0].notes
    )
    (joined,) = load_experiments([tmp_path], max_gap_s=600.0)
    assert len(joined) == 60 + 30 + 60  # 30 missing samples in 310 s from tick 59 to 60
    assert_allclose(joined.column("T_degC")[59:91], np.linspace(value(59), value(60), 32))


def test_a_restart_splits_a_run_and_contiguous_joins_across_it(tmp_path: Path) -> None:
    """A daemon restart starts a new run (a new experiment) unless asked to join files by time."""
    with make(tmp_path) as first:
        write(first, range(60))
    with make(tmp_path) as second:
        write(second, range(60, 120))
    experiments = load_experiments([tmp_path])
    assert [len(e) for e in experiments] == [60, 60]
    assert any("starts another run (compd was started again)" in n for n in experiments[0].notes)
    (joined,) = load_experiments([tmp_path], joining="contiguous")
    assert_allclose(joined.column("T_degC"), [value(k) for k in range(120)])


def test_a_run_missing_one_of_its_files_is_split_there(tmp_path: Path) -> None:
    """Without a file of the run, the file after it starts a new experiment, naming the one missing."""
    with make(tmp_path) as rec:
        write(rec, range(240))
    missing = recorded(tmp_path)[1]
    missing.unlink()
    experiments = load_experiments([tmp_path])
    assert [len(e) for e in experiments] == [60, 120]
    assert any(f"{missing.name}, is not given" in n for n in experiments[0].notes)


def test_files_without_run_marks_stay_one_experiment_each_unless_contiguous(
    tmp_path: Path,
) -> None:
    """Older recordings and other loggers' files are separate experiments; contiguous joins them by time."""
    times = pd.date_range("2026-11-23T10:15:00Z", periods=120, freq="10s")
    frame = pd.DataFrame({"timestamp": times.strftime("%Y-%m-%dT%H:%M:%S+00:00"), "T_degC": 20.0})
    frame.iloc[:60].to_csv(tmp_path / "a.csv", index=False)
    frame.iloc[60:].to_csv(tmp_path / "b.csv", index=False)
    experiments = load_experiments([tmp_path])
    assert [len(e) for e in experiments] == [60, 60]
    assert "1 file(s) without run marks continue the file before them" in experiments[0].notes[-2]
    assert "--experiments contiguous joins" in experiments[0].notes[-1]
    assert [len(e) for e in load_experiments([tmp_path], joining="contiguous")] == [120]


def test_contiguous_needs_timestamps_to_join(tmp_path: Path) -> None:
    """Files with seconds only (time_s) cannot show that one continues the other: never joined."""
    for name, first in (("a.csv", 0), ("b.csv", 60)):
        pd.DataFrame({"time_s": np.arange(first, first + 60) * TS_S, "T_degC": 20.0}).to_csv(
            tmp_path / name, index=False
        )
    experiments = load_experiments([tmp_path], joining="contiguous")
    assert [len(e) for e in experiments] == [60, 60]
    assert any("no timestamps" in n for n in experiments[0].notes)


@pytest.fixture
def two_runs(tmp_path: Path) -> Path:
    """A folder of two runs (a restart between them), two files each."""
    folder = tmp_path / "records"
    for ticks in (range(120), range(120, 240)):
        with make(folder) as rec:
            write(rec, ticks)
    return folder


def test_commands_join_runs_and_take_the_override(two_runs: Path) -> None:
    """simulate over a folder of two runs of two files each: two experiments; per-file: four."""
    model = two_runs.parent / "m.yaml"
    compd("fit", "--data", two_runs, "--output", "disp_um", "--inputs", "T_degC",
          "--method", "mlr", "--out", model)  # fmt: skip
    out = two_runs.parent / "pred.csv"
    compd("simulate", model, two_runs, "--out", out)
    assert sorted(set(pd.read_csv(out)["experiment"])) == [0, 1]
    compd("simulate", model, two_runs, "--experiments", "per-file", "--out", out)
    assert sorted(set(pd.read_csv(out)["experiment"])) == [0, 1, 2, 3]


def test_a_command_of_one_record_takes_one_run_and_refuses_two(two_runs: Path) -> None:
    """residual reads a run's files as one record, and refuses a folder of two runs, saying what it holds.

    report reads a run's files as one record too, and two runs end to end, each from its own start.
    """
    model = two_runs.parent / "m.yaml"
    compd("fit", "--data", two_runs, "--output", "disp_um", "--inputs", "T_degC",
          "--method", "mlr", "--out", model)  # fmt: skip
    first_run = recorded(two_runs)[:2]
    page = two_runs.parent / "r.html"
    compd("report", model, *first_run, "--out", page)
    assert "experiments (separate files or runs) end to end" not in page.read_text()
    compd("report", model, two_runs, "--out", page)
    assert "2 experiments (separate files or runs) end to end" in page.read_text()
    with pytest.raises(AssertionError, match=r"4 files, 2 runs of 20\.0 min each from mill-a"):
        compd("residual", model, two_runs, "--out", two_runs.parent / "r.yaml")
