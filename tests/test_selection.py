"""Column selection by names, globs and ``all``."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest

from compd.errors import DataFileError
from compd.files.data import load_data
from compd.toolkit.selection import select_columns


@pytest.fixture
def data(tmp_path: Path):
    path = tmp_path / "d.csv"
    columns = ["T1", "T2", "T10", "spindle_speed_rpm", "disp_ch1", "x_pos_mm", "z_um"]
    frame = pd.DataFrame({name: [1.0, 2.0, 3.0] for name in columns})
    frame.insert(0, "time_s", [0.0, 1.0, 2.0])
    frame.to_csv(path, index=False)
    return load_data(path)


def test_all_is_every_signal_but_displacements_and_the_excluded(data) -> None:
    """``all`` leaves out ``disp_*``, ``*_um`` and what the caller excludes, in file order."""
    chosen = select_columns(data, "all", option="--inputs", exclude=["x_pos_mm"])
    assert chosen == ["T1", "T2", "T10", "spindle_speed_rpm"]


def test_names_stay_as_given_and_globs_add_what_is_new(data) -> None:
    """A plain name is kept even when repeated (the caller refuses it); a glob adds only new columns."""
    assert select_columns(data, "T2, T*,T2", option="--inputs") == ["T2", "T1", "T10", "T2"]


def test_a_glob_never_matches_an_excluded_column(data) -> None:
    """``*`` with the output excluded is every other column."""
    assert "z_um" not in select_columns(data, "*", option="--inputs", exclude=["z_um"])


def test_a_pattern_matching_nothing_lists_the_columns(data) -> None:
    """The error names the pattern, the option and the file's columns."""
    with pytest.raises(DataFileError, match=r"'t\*' matches no column.*T1, T2, T10"):
        select_columns(data, "t*", option="--inputs")


def test_all_leaves_out_what_compds_recorder_adds_beside_the_signals(tmp_path: Path) -> None:
    """A recording of compd's own: ``all`` is its signals, not their health, readings or status."""
    path = tmp_path / "rec.csv"
    columns = ["T_spindle_degC", "read.T_spindle_degC", "health.T_spindle_degC", "model.disp_z_um"]
    columns += ["offset.Z_um", "readback.Z_um", "gain.g1", "status", "heartbeat"]
    frame = pd.DataFrame({name: [1.0, 2.0, 3.0] for name in columns})
    frame.insert(0, "time_s", [0.0, 1.0, 2.0])
    frame.to_csv(path, index=False)
    assert select_columns(load_data(path), "all", option="--inputs") == ["T_spindle_degC"]
