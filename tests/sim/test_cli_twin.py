"""compd twin: writes a data file that the rest of compd reads, and refuses bad requests with exit 2."""

from pathlib import Path

import numpy as np
import pytest

from compd.cli import main
from compd.files.data import load_data
from compd.sim import COLUMNS


def test_twin_writes_a_csv_that_load_data_reads(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """compd twin writes a CSV with the contract columns at the asked sample time, readable by load_data."""
    out = tmp_path / "door.csv"
    code = main(
        [
            "twin",
            "--scenario",
            "door",
            "--hours",
            "1",
            "--out",
            str(out),
            "--seed",
            "3",
            "--sample-time-s",
            "10",
        ]
    )
    assert code == 0, capsys.readouterr().err
    data = load_data(out)
    assert data.sample_time_s == 10.0
    assert len(data) == 361
    assert list(data.columns) == list(COLUMNS[1:])
    assert "wrote 361 samples" in capsys.readouterr().out


def test_an_unknown_scenario_exits_2_naming_the_scenarios(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A misspelt scenario ends with exit status 2 and a message listing the scenarios; nothing is written."""
    out = tmp_path / "x.csv"
    code = main(["twin", "--scenario", "calibraton", "--hours", "1", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2
    assert "no scenario 'calibraton'" in err and "speed_spectrum" in err
    assert not out.exists()


def test_bad_hours_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A non-positive run length ends with exit status 2 and says what hours must be."""
    code = main(["twin", "--scenario", "door", "--hours", "0", "--out", str(tmp_path / "x.csv")])
    assert code == 2
    assert "hours must be above 0" in capsys.readouterr().err


def test_an_unwritable_output_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """An output path in a missing directory ends with exit status 2 naming the path."""
    out = tmp_path / "missing" / "x.csv"
    code = main(
        ["twin", "--scenario", "door", "--hours", "0.1", "--out", str(out), "--sample-time-s", "10"]
    )
    assert code == 2
    assert str(out) in capsys.readouterr().err


def test_feed_positions_run_is_written_with_axis_positions(tmp_path: Path) -> None:
    """`--scenario feed_positions` writes the feed run plus the X/Z positions and screw temperatures."""
    out = tmp_path / "positions.csv"
    assert main(["twin", "--scenario", "feed_positions", "--hours", "1", "--sample-time-s", "10",
                 "--out", str(out)]) == 0  # fmt: skip
    data = load_data(out)
    for column in ("X_position_mm", "Z_position_mm", "T_x_screw_degC", "T_z_screw_degC"):
        assert data.has(column)
    assert len(np.unique(data.column("X_position_mm"))) >= 2


def test_a_realistic_run_is_written_with_sixteen_unnamed_temperatures(tmp_path: Path) -> None:
    """`--scenario real_verify` writes time, speed, T1..T16 and disp_x/y/z_um, readable by load_data."""
    out = tmp_path / "verify.csv"
    assert main(["twin", "--scenario", "real_verify", "--hours", "2", "--sample-time-s", "60",
                 "--seed", "4", "--out", str(out)]) == 0  # fmt: skip
    data = load_data(out)
    assert len(data) == 121
    assert [f"T{i}" for i in range(1, 17)] == [c for c in data.columns if c.startswith("T")]
    assert data.has("disp_z_um") and data.column("disp_z_um")[0] == 0.0


def test_a_realistic_run_refuses_the_air_conditioned_option(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """--air-conditioned needs a T_ambient_degC column: on a realistic run it exits 2, writing nothing."""
    out = tmp_path / "x.csv"
    code = main(["twin", "--scenario", "real_record", "--hours", "1", "--sample-time-s", "60",
                 "--air-conditioned", "--out", str(out)])  # fmt: skip
    assert code == 2
    assert "--air-conditioned" in capsys.readouterr().err
    assert not out.exists()
