"""Recorder: rotating CSV files that compd's own data loader and compare command read back."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
from numpy.testing import assert_allclose

from compd.cli import main
from compd.errors import RecorderError
from compd.files.data import load_data
from compd.service.recording.recorder import Recorder

CONFIG = Path(__file__).parents[2] / "config"
DATA = CONFIG / "example_spectrum.csv"
SEED000 = CONFIG / "seed000_hmc_tf.yaml"
T0_S = 1_795_428_900.0  # 2026-11-23T10:15:00Z
BIG = 1 << 30
TOTAL = 4 * BIG  # the open file's budget (BIG) plus closed files


class FakeClock:
    """Seconds since the epoch that only move when the test says so."""

    def __init__(self, now_s: float = T0_S) -> None:
        self.now_s = now_s

    def __call__(self) -> float:
        return self.now_s


def recordings(directory: Path) -> list[Path]:
    return sorted(directory.glob("compd-*.csv"))


def body(path: Path) -> list[str]:
    """A recording's header and rows: its lines after the ``# key: value`` metadata."""
    return [line for line in path.read_text().splitlines() if not line.startswith("#")]


def make(directory: Path, clock: FakeClock | None = None, **limits: float) -> Recorder:
    """A recorder with no limit in the way except those given."""
    options = {"max_file_bytes": BIG, "max_file_age_s": 1e6, "max_total_bytes": TOTAL} | limits
    return Recorder(directory, clock=clock or FakeClock(), **options)


def test_a_recording_loads_with_load_data(tmp_path):
    """A recorded file is a valid data file: UTC timestamps, the row's columns, 1 s sample time."""
    clock = FakeClock()
    with make(tmp_path, clock, max_file_age_s=3600) as rec:
        for k in range(10):
            rec.record(
                {"T_spindle_degC": 20.0 + 0.1 * k, "speed_rpm": 1000 * k, "offset_z_um": -1.5}
            )
            clock.now_s += 1.0
    (path,) = recordings(tmp_path)
    assert path.name == "compd-20261123T101500Z.csv"
    assert body(path)[:2] == [
        "timestamp,T_spindle_degC,speed_rpm,offset_z_um",
        "2026-11-23T10:15:00.000+00:00,20,0,-1.5",
    ]
    data = load_data(path)
    assert data.sample_time_s == 1.0 and len(data) == 10
    assert data.start_time is not None and data.start_time.utcoffset().total_seconds() == 0
    assert_allclose(data.column("T_spindle_degC"), 20.0 + 0.1 * pd.RangeIndex(10).to_numpy())
    assert list(data.columns) == ["T_spindle_degC", "speed_rpm", "offset_z_um"]


def test_compare_on_a_recording_matches_compare_on_the_source(tmp_path, capsys):
    """Signals recorded by the service give compd compare exactly the figures of the logged source data."""
    source = pd.read_csv(DATA).iloc[:720]  # 2 h at 10 s
    original = tmp_path / "source.csv"
    source.to_csv(original, index=False)
    directory = tmp_path / "rec"
    with make(directory) as rec:
        for row in source.to_dict("records"):
            t_s = row.pop("time_s")
            rec.record(row, at_s=T0_S + t_s)
    (recorded,) = recordings(directory)
    reports = []
    for path in (original, recorded):
        assert main(["compare", str(SEED000), str(path), "--json"]) == 0
        reports.append(json.loads(capsys.readouterr().out))
    assert reports[1]["samples"] == 720 and reports[1]["sample_time_s"] == 10.0
    for key, value in reports[0]["outputs"]["disp_z_um"].items():
        assert reports[1]["outputs"]["disp_z_um"][key] == pytest.approx(value, rel=1e-9), key


def test_files_rotate_by_size_and_keep_every_row_in_order(tmp_path):
    """No file exceeds max_file_bytes; the files, in name order, hold every row once, in order."""
    clock = FakeClock()
    with make(tmp_path, clock, max_file_bytes=2000) as rec:
        for k in range(300):
            rec.record({"k": k, "x_um": k * 0.25})
            clock.now_s += 0.5  # two files may start in one second: named -1, -2...
    files = recordings(tmp_path)
    assert len(files) > 5
    assert all(path.stat().st_size <= 2000 for path in files)
    order = sorted(files, key=lambda p: (p.name.split("Z")[0], int(p.stem.partition("Z-")[2] or 0)))
    rows = pd.concat([pd.read_csv(path, comment="#") for path in order])
    assert rows["k"].tolist() == list(range(300))


def test_files_rotate_by_age(tmp_path):
    """A row written max_file_age_s after a file's first row starts a new file named by its own time."""
    clock = FakeClock()
    with make(tmp_path, clock, max_file_age_s=600) as rec:
        for _ in range(1500):
            rec.record({"x_um": 1.0})
            clock.now_s += 1.0
    names = [path.name for path in recordings(tmp_path)]
    assert names == [
        "compd-20261123T101500Z.csv",
        "compd-20261123T102500Z.csv",
        "compd-20261123T103500Z.csv",
    ]
    assert [len(pd.read_csv(tmp_path / name, comment="#")) for name in names] == [600, 600, 300]


def test_other_keys_start_a_new_file(tmp_path):
    """A row with other keys (a new model) closes the file: every file has one header."""
    clock = FakeClock()
    with make(tmp_path, clock) as rec:
        rec.record({"a": 1, "b": 2})
        clock.now_s += 1
        rec.record({"b": 3, "a": 4})  # same keys in another order: same file, header order
        clock.now_s += 1
        rec.record({"a": 5, "c": 6})
    first, second = recordings(tmp_path)
    assert body(first)[1:] == [
        "2026-11-23T10:15:00.000+00:00,1,2",
        "2026-11-23T10:15:01.000+00:00,4,3",
    ]
    assert body(second)[0] == "timestamp,a,c"


def test_oldest_files_are_deleted_to_stay_under_the_total(tmp_path):
    """Recordings never exceed max_total_bytes; the newest survive, other files are never touched."""
    (tmp_path / "notes.txt").write_text("keep me")
    previous_run = tmp_path / "compd-20200101T000000Z.csv"
    previous_run.write_text("timestamp,x\n" + "y" * 3000)
    clock = FakeClock()
    with make(tmp_path, clock, max_file_bytes=1000, max_total_bytes=4000) as rec:
        for k in range(500):
            rec.record({"k": k})
            clock.now_s += 1.0
            total = sum(path.stat().st_size for path in recordings(tmp_path))
            assert total <= 4000
    assert (tmp_path / "notes.txt").read_text() == "keep me"
    files = recordings(tmp_path)
    assert "compd-20200101T000000Z.csv" not in [path.name for path in files]
    assert pd.read_csv(files[-1], comment="#")["k"].iloc[-1] == 499


def test_cells_are_quoted_and_gaps_stay_gaps(tmp_path):
    """Text with commas or quotes is CSV-quoted, bools are 1/0, NaN is a gap that load_data fills."""
    clock = FakeClock()
    with make(tmp_path, clock) as rec:
        for k in range(3):
            rec.record({"on": k > 0, "state": 'hold, "slew"'})
            clock.now_s += 1.0
        for k in range(3):
            rec.record({"x_um": math.nan if k == 1 else float(k)})
            clock.now_s += 1.0
    text_file, numbers_file = recordings(tmp_path)
    frame = pd.read_csv(text_file, comment="#")
    assert frame["state"].tolist() == ['hold, "slew"'] * 3
    assert frame["on"].tolist() == [0, 1, 1]
    assert body(numbers_file)[2].endswith(",nan")
    assert_allclose(load_data(numbers_file).column("x_um"), [0.0, 1.0, 2.0])


def test_a_time_column_name_is_refused(tmp_path):
    """A signal named like a time column would make the file unreadable, so it is refused up front."""
    rec = make(tmp_path, max_file_age_s=1)
    with pytest.raises(RecorderError, match="'time'"):
        rec.record({"time": 1.0})
    assert recordings(tmp_path) == []


def test_an_unwritable_directory_is_a_recorder_error(tmp_path):
    """A directory that cannot be created is a RecorderError naming it, not an OSError in the loop."""
    blocker = tmp_path / "file"
    blocker.write_text("")
    rec = make(blocker / "rec", max_file_age_s=1)
    with pytest.raises(RecorderError, match=r"cannot create a recording in .*rec"):
        rec.record({"x": 1.0})


_DISK_FULL_SCRIPT = """
import itertools, resource, signal, sys
from pathlib import Path
from compd.errors import RecorderError
from compd.service.recording.recorder import Recorder
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # EFBIG instead of death, as ENOSPC would be
resource.setrlimit(resource.RLIMIT_FSIZE, (1000, 1000))
rec = Recorder(Path(sys.argv[1]), max_file_bytes=10**9, max_file_age_s=1e9, max_total_bytes=10**10,
               clock=itertools.count(1795428900.0).__next__)
errors = 0
for k in range(100):
    try:
        rec.record({"k": k, "x_um": 0.125})
    except RecorderError as exc:
        errors += 1
        message = str(exc)
rec.close()
print(errors, rec.take_lost_rows(), message)
"""


def test_disk_full_keeps_whole_lines_and_recording_resumes(tmp_path):
    """A failed write leaves whole rows only, raises RecorderError (its row counted lost); later rows: a new file."""
    done = subprocess.run(
        [sys.executable, "-c", _DISK_FULL_SCRIPT, str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    )
    errors, lost, message = done.stdout.split(" ", 2)
    assert int(errors) > 0 and "cannot write to" in message
    assert int(lost) == int(errors)  # each failed write lost its one row, and was counted
    files = recordings(tmp_path)
    assert len(files) >= 2  # recording resumed in a fresh file after the failure
    for path in files:
        text = path.read_text()
        assert text.endswith("\n") and len(text) <= 1000
        assert all(len(line.split(",")) == 3 for line in body(path))
        load_data(path)


def rec_file(directory: Path) -> Path:
    (path,) = recordings(directory)
    return path


def test_a_clock_set_back_starts_a_new_file(tmp_path):
    """Times that stop increasing (NTP stepping the clock back) go to a new file, so every file loads."""
    clock = FakeClock()
    with make(tmp_path, clock) as rec:
        for step_s in (1, 1, 1, -10, 1, 1):
            clock.now_s += step_s
            rec.record({"x_um": 1.0})
    files = recordings(tmp_path)
    assert len(files) == 2
    assert sorted(len(load_data(path)) for path in files) == [3, 3]


def test_an_empty_row_is_refused(tmp_path):
    """A row without columns would make a file with only times, which no loader accepts."""
    with pytest.raises(RecorderError, match="empty row"):
        make(tmp_path).record({})
