"""Data files load onto a uniform grid; each repair is noted, each refusal names file, line, fix."""

from __future__ import annotations

import sys
from collections.abc import Iterable
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from numpy.testing import assert_allclose, assert_array_equal

from compd.errors import DataFileError
from compd.files.data import DataSet, load_data

HEADER = "time_s,T_spindle_degC,T_shopfloor_degC"


def write(tmp_path: Path, text: str, name: str = "calib.csv") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def series(n: int = 20, *, drop: Iterable[int] = (), cells: dict[int, str] | None = None) -> str:
    """A 15 s CSV: T_spindle_degC = 20 + 0.5 i and T_shopfloor_degC = 19 + 0.1 i (linear in i,
    so interpolation recovers them exactly).

    ``drop`` leaves rows out; ``cells`` replaces the T_spindle_degC cell of a row.
    """
    cells = cells or {}
    lines = [HEADER]
    for i in range(n):
        if i not in drop:
            lines.append(f"{i * 15},{cells.get(i, f'{20 + 0.5 * i:g}')},{19 + 0.1 * i:g}")
    return "\n".join(lines) + "\n"


def refusal(path: Path, *, max_gap_s: float = 60.0, resample: bool = False) -> str:
    """The message of the DataFileError that loading ``path`` raises; it starts with the file."""
    with pytest.raises(DataFileError) as info:
        load_data(path, max_gap_s=max_gap_s, resample=resample)
    message = str(info.value)
    assert message.startswith(f"{path}: ")
    return message


# --- time column -------------------------------------------------------------------------------


def test_time_s_from_any_origin_is_shifted_to_start_at_zero(tmp_path: Path) -> None:
    """time_s may start anywhere: the first value is subtracted, the signals are read exactly."""
    path = write(
        tmp_path,
        "time_s,T_spindle_degC,spindle_speed_rpm\n1000,20.5,0\n1010,20.625,3200\n1020,20.75,3200\n",
    )
    data = load_data(path)
    assert isinstance(data, DataSet)
    assert data.path == str(path)
    assert_array_equal(data.time_s, [0.0, 10.0, 20.0])
    assert data.sample_time_s == 10.0
    assert list(data.columns) == ["T_spindle_degC", "spindle_speed_rpm"]
    assert_array_equal(data.column("T_spindle_degC"), [20.5, 20.625, 20.75])
    assert data.column("spindle_speed_rpm").dtype == np.float64
    assert (len(data), data.start_time, data.notes) == (3, None, ())
    assert data.has("spindle_speed_rpm")
    assert not data.has("time_s")


@pytest.mark.parametrize("name", ["time", "timestamp", "datetime"])
def test_iso_timestamps_give_start_time_and_seconds_from_the_first_sample(
    tmp_path: Path, name: str
) -> None:
    """ISO-8601 times (T or space separated) set start_time; time_s counts from 0 in 15 s steps."""
    stamps = [
        "2024-03-05T14:30:00",
        "2024-03-05T14:30:15",
        "2024-03-05 14:30:30",
        "2024-03-05T14:30:45",
    ]
    path = write(tmp_path, f"{name},T\n" + "".join(f"{s},{i}\n" for i, s in enumerate(stamps)))
    data = load_data(path)
    assert data.start_time == datetime(2024, 3, 5, 14, 30)
    assert_array_equal(data.time_s, [0.0, 15.0, 30.0, 45.0])
    assert data.sample_time_s == 15.0


def test_timestamps_with_a_utc_offset_keep_it_in_start_time(tmp_path: Path) -> None:
    """An offset (+01:00) makes start_time timezone-aware with that offset."""
    path = write(
        tmp_path, "timestamp,T\n2024-01-05T10:00:00+01:00,1\n2024-01-05T10:00:15+01:00,2\n"
    )
    start = load_data(path).start_time
    assert start is not None
    assert start.utcoffset() == timedelta(hours=1)
    assert start.replace(tzinfo=None) == datetime(2024, 1, 5, 10, 0)


def test_a_daylight_saving_change_is_read_as_absolute_time_and_noted(tmp_path: Path) -> None:
    """Offsets going from +01:00 to +02:00 are absolute instants: 15 s stays 15 s, noted."""
    path = write(
        tmp_path,
        "timestamp,T\n2024-03-31T01:59:30+01:00,1\n2024-03-31T01:59:45+01:00,2\n"
        "2024-03-31T03:00:00+02:00,3\n",
    )
    data = load_data(path)
    assert_array_equal(data.time_s, [0.0, 15.0, 30.0])
    assert len(data.notes) == 1
    assert "+01:00, +02:00" in data.notes[0]


def test_timestamps_with_and_without_utc_offset_are_refused(tmp_path: Path) -> None:
    """A naive timestamp after an offset one is ambiguous: refused naming its line."""
    path = write(tmp_path, "timestamp,T\n2024-01-05T10:00:00+01:00,1\n2024-01-05T10:00:15,2\n")
    message = refusal(path)
    assert "line 3, column 'timestamp'" in message
    assert "mixed time zones" in message
    assert "UTC offset" in message


def test_an_unparsable_timestamp_is_refused_naming_its_line(tmp_path: Path) -> None:
    """A cell that is not ISO-8601 names its line, its text and the expected form."""
    path = write(
        tmp_path, "time,T\n2024-01-05T10:00:00,1\n2024-01-05T10:00:15,2\n05/01/2024 10:00:30,3\n"
    )
    message = refusal(path)
    assert "line 4, column 'time': '05/01/2024 10:00:30' is not an ISO-8601 timestamp" in message
    assert "2024-03-05T14:30:00" in message


def test_seconds_in_a_timestamp_column_suggest_renaming_it_time_s(tmp_path: Path) -> None:
    """Numbers in a column named 'time' are refused with the fix: name it time_s."""
    message = refusal(write(tmp_path, "time,T\n0,1\n10,2\n"))
    assert "line 2, column 'time'" in message
    assert "name it 'time_s'" in message


def test_time_going_backwards_is_refused_naming_the_line_and_both_times(tmp_path: Path) -> None:
    """A time before the previous row's names the line and both times."""
    message = refusal(write(tmp_path, "time_s,T\n0,1\n10,2\n5,3\n30,4\n"))
    assert "line 4, column 'time_s': time 5 s is before the time 10 s on line 3" in message
    assert "strictly increase" in message


def test_a_repeated_time_is_refused(tmp_path: Path) -> None:
    """Two rows with the same time are refused naming the second one's line."""
    message = refusal(write(tmp_path, "time_s,T\n0,1\n10,2\n10,3\n30,4\n"))
    assert "line 4, column 'time_s': time 10 s is the same as the time 10 s on line 3" in message


def test_an_empty_time_cell_is_refused(tmp_path: Path) -> None:
    """A row without a time cannot be placed: refused naming its line."""
    message = refusal(write(tmp_path, "time_s,T\n0,1\n,2\n20,3\n"))
    assert "line 3, column 'time_s': the time is empty" in message


def test_a_time_that_is_not_a_number_is_refused(tmp_path: Path) -> None:
    """time_s holds seconds: any other text is refused with the line and the text."""
    message = refusal(write(tmp_path, "time_s,T\n0,1\n10s,2\n20,3\n"))
    assert "line 3, column 'time_s': '10s' is not a time in seconds" in message


def test_a_missing_time_column_is_refused_listing_the_accepted_names(tmp_path: Path) -> None:
    """Without a time column the message lists every accepted name and the file's columns."""
    message = refusal(write(tmp_path, "t,T\n0,1\n10,2\n"))
    assert "line 1: no time column" in message
    for name in ("'time_s'", "'time'", "'timestamp'", "'datetime'", "['t', 'T']"):
        assert name in message


def test_two_time_columns_are_refused(tmp_path: Path) -> None:
    """time_s beside timestamp is ambiguous: keep one."""
    message = refusal(
        write(tmp_path, "time_s,timestamp,T\n0,2024-01-05T10:00:00,1\n10,2024-01-05T10:00:10,2\n")
    )
    assert "several time columns: ['time_s', 'timestamp']" in message


# --- header and cells ---------------------------------------------------------------------------


def test_a_duplicate_column_is_refused(tmp_path: Path) -> None:
    """Two columns of one name are refused naming it and both positions."""
    message = refusal(write(tmp_path, "time_s,T,T\n0,1,1\n10,2,2\n"))
    assert "line 1: column 'T' appears twice (columns 2 and 3)" in message


def test_an_unnamed_column_is_refused(tmp_path: Path) -> None:
    """An empty header cell (a trailing comma) is refused with its position."""
    message = refusal(write(tmp_path, "time_s,T,\n0,1,1\n10,2,2\n"))
    assert "line 1: column 3 has no name" in message


@pytest.mark.parametrize(
    ("text", "problem"),
    [
        ("time_s,T\n", "0 data row(s); at least 2 are needed"),
        ("time_s,T\n0,1\n", "1 data row(s); at least 2 are needed"),
        ("", "there is no header row"),
    ],
)
def test_fewer_than_two_data_rows_are_refused(tmp_path: Path, text: str, problem: str) -> None:
    """A sample time needs at least two rows; an empty file has not even a header."""
    assert problem in refusal(write(tmp_path, text))


def test_a_row_with_extra_cells_is_refused_naming_its_line(tmp_path: Path) -> None:
    """A row with more cells than the header has names is refused naming its line."""
    message = refusal(write(tmp_path, "time_s,T\n0,1\n10,2,3\n20,3\n"))
    assert "line 3: 3 cells, but the header names 2" in message


def test_a_non_numeric_cell_is_refused_with_line_column_text_and_fix(tmp_path: Path) -> None:
    """The whole message, as the user reads it."""
    path = write(tmp_path, series(5, cells={2: "abc"}))
    assert refusal(path) == (
        f"{path}: line 4, column 'T_spindle_degC': 'abc' is not a number. "
        "Fix the cell or leave it empty to mark a gap"
    )


@pytest.mark.parametrize(
    ("cell", "problem"),
    [
        ("'1,5'", "'1,5' is not a number"),
        ("NA", "'NA' is not a number"),
        ("True", "'True' is not a number"),
        ("inf", "'inf' is not a finite number"),
        ("-inf", "'-inf' is not a finite number"),
        ("1e400", "is not a finite number"),
    ],
)
def test_only_empty_and_nan_cells_are_gaps_other_text_and_infinity_are_refused(
    tmp_path: Path, cell: str, problem: str
) -> None:
    """Text other than '', NaN, nan, and infinite numbers are bad cells, not gaps."""
    path = write(tmp_path, series(5, cells={3: cell.replace("'", '"')}))
    message = refusal(path)
    assert "line 5, column 'T_spindle_degC'" in message
    assert problem in message


def test_the_message_counts_the_other_bad_cells_of_the_column(tmp_path: Path) -> None:
    """The first bad cell is named; the others in that column are counted."""
    message = refusal(write(tmp_path, series(6, cells={1: "x", 3: "y", 4: "z"})))
    assert "line 3" in message
    assert "'x' is not a number (2 more bad cells in this column)" in message


def test_blank_lines_are_skipped_without_shifting_line_numbers(tmp_path: Path) -> None:
    """Blank lines carry no row, and a later bad cell is still reported on its real line."""
    assert len(load_data(write(tmp_path, "time_s,T\n0,1\n\n10,2\n20,3\n\n"))) == 3
    message = refusal(write(tmp_path, "time_s,T\n0,1\n\n10,2\n20,x\n"))
    assert "line 5, column 'T'" in message


def test_an_excel_byte_order_mark_is_ignored(tmp_path: Path) -> None:
    """A UTF-8 BOM before the header does not hide the time column."""
    path = tmp_path / "excel.csv"
    path.write_bytes("\ufefftime_s,T\n0,1\n10,2\n".encode())
    assert_array_equal(load_data(path).column("T"), [1.0, 2.0])


def test_a_missing_file_is_a_data_file_error(tmp_path: Path) -> None:
    """An absent file is reported as compd's error, not an OSError."""
    assert "cannot read the file" in refusal(tmp_path / "absent.csv")


# --- grid: jitter, missing rows, irregular sampling ---------------------------------------------


def test_jitter_up_to_10_percent_of_a_sample_is_snapped_to_the_grid(tmp_path: Path) -> None:
    """Rows up to 10 % of Ts off their grid point (here exactly 10 %) land on it unchanged."""
    times = [0, 10, 21, 30, 40, 50, 59, 70]
    path = write(tmp_path, "time_s,T\n" + "".join(f"{t},{i}\n" for i, t in enumerate(times)))
    data = load_data(path)
    assert data.sample_time_s == 10.0
    assert_array_equal(data.time_s, np.arange(8) * 10.0)
    assert_array_equal(data.column("T"), np.arange(8.0))
    assert data.notes == ()


def test_missing_rows_become_gaps_that_are_interpolated_and_noted(tmp_path: Path) -> None:
    """Three rows absent from a 15 s log are filled in every column, in one note."""
    data = load_data(write(tmp_path, series(20, drop=(8, 9, 10))))
    assert_array_equal(data.time_s, np.arange(20) * 15.0)
    assert_allclose(data.column("T_spindle_degC"), 20 + 0.5 * np.arange(20))
    assert_allclose(data.column("T_shopfloor_degC"), 19 + 0.1 * np.arange(20))
    assert data.notes == ("all columns: 3 missing samples at 120-150 s interpolated",)


def test_a_row_off_the_grid_is_refused_suggesting_resample(tmp_path: Path) -> None:
    """A row 15 % of a sample off the grid is irregular sampling: line, count and --resample."""
    times = [0, 10, 21.5, 30, 40, 50]
    message = refusal(
        write(tmp_path, "time_s,T\n" + "".join(f"{t},{i}\n" for i, t in enumerate(times)))
    )
    assert "line 4, column 'time_s': time 21.5 s is 1.5 s off the sampling grid" in message
    assert "1 of 6 rows" in message
    assert "--resample" in message


def test_two_rows_on_one_grid_point_are_irregular(tmp_path: Path) -> None:
    """Rows 0.5 s apart in a 10 s log cannot both be samples: refused naming both lines."""
    message = refusal(write(tmp_path, "time_s,T\n0,1\n10,2\n10.5,3\n20,4\n30,5\n40,6\n"))
    assert "line 4" in message
    assert "on line 3" in message
    assert "--resample" in message


def test_resample_interpolates_every_column_onto_the_median_step_grid(tmp_path: Path) -> None:
    """resample=True interpolates each column linearly; a note counts the off-grid rows."""
    times = np.array([0.0, 10, 25, 30, 40, 50, 60])
    text = "time_s,lin,sq\n" + "".join(f"{t:g},{2 * t:g},{t * t:g}\n" for t in times)
    data = load_data(write(tmp_path, text), resample=True)
    assert data.sample_time_s == 10.0
    assert_array_equal(data.time_s, np.arange(7) * 10.0)
    assert_allclose(data.column("lin"), 2 * data.time_s)
    assert_allclose(data.column("sq"), [0, 100, 100 + 10 / 15 * 525, 900, 1600, 2500, 3600])
    assert len(data.notes) == 1
    assert "1 of 7 rows" in data.notes[0]
    assert "10 s grid" in data.notes[0]


def test_resample_does_not_bridge_a_long_hole_in_the_log(tmp_path: Path) -> None:
    """Resampling never interpolates across more than max_gap_s without rows."""
    times = [0, 10, 21.5, 30, 40, 200, 210, 220, 230]
    message = refusal(
        write(tmp_path, "time_s,T\n" + "".join(f"{t},{i}\n" for i, t in enumerate(times))),
        resample=True,
    )
    assert "between lines 6 and 7" in message
    assert "no rows for 150 s" in message


# --- gaps ---------------------------------------------------------------------------------------


def test_empty_and_nan_cells_are_gaps_interpolated_per_column(tmp_path: Path) -> None:
    """'', NaN and nan in one column are filled linearly; the note names column, count and span."""
    data = load_data(write(tmp_path, series(20, cells={8: "", 9: "NaN", 10: "nan"})))
    assert_allclose(data.column("T_spindle_degC"), 20 + 0.5 * np.arange(20))
    assert data.notes == ("T_spindle_degC: 3 missing samples at 120-150 s interpolated",)


def test_a_gap_lasting_exactly_max_gap_s_is_filled(tmp_path: Path) -> None:
    """4 missing 15 s samples last 60 s: at the default limit, so they are interpolated."""
    data = load_data(write(tmp_path, series(20, cells=dict.fromkeys(range(8, 12), ""))))
    assert data.notes == ("T_spindle_degC: 4 missing samples at 120-165 s interpolated",)


def test_a_gap_longer_than_max_gap_s_is_refused_naming_column_span_lines_and_fix(
    tmp_path: Path,
) -> None:
    """5 missing samples (75 s) exceed 60 s: refused naming lines, column, span and --max-gap-s."""
    path = write(tmp_path, series(20, cells=dict.fromkeys(range(8, 13), "")))
    message = refusal(path)
    assert "lines 10-14, column 'T_spindle_degC'" in message
    assert "5 missing samples at 120-180 s (75 s) is longer than max_gap_s = 60 s" in message
    assert "--max-gap-s" in message
    assert load_data(path, max_gap_s=75).notes == (
        "T_spindle_degC: 5 missing samples at 120-180 s interpolated",
    )


def test_missing_rows_longer_than_max_gap_s_are_refused_between_their_neighbours(
    tmp_path: Path,
) -> None:
    """Five absent rows in a row are a 75 s hole between two lines of the file."""
    message = refusal(write(tmp_path, series(20, drop=range(8, 13))))
    assert "between lines 9 and 10: no rows for 75 s after 105 s" in message
    assert "--max-gap-s" in message


@pytest.mark.parametrize(
    ("rows", "where", "edge"), [((0, 1), "lines 2-3", "start"), ((19,), "line 21", "end")]
)
def test_a_gap_at_the_start_or_end_is_refused(
    tmp_path: Path, rows: tuple[int, ...], where: str, edge: str
) -> None:
    """A gap without a neighbour on one side cannot be interpolated: trim the file."""
    message = refusal(write(tmp_path, series(20, cells=dict.fromkeys(rows, ""))))
    assert f"{where}, column 'T_spindle_degC'" in message
    assert f"at the {edge} of the column cannot be interpolated" in message
    assert "Trim the file" in message


def test_a_column_without_values_is_refused(tmp_path: Path) -> None:
    """An all-empty column is refused by name."""
    message = refusal(write(tmp_path, "time_s,T,U\n0,1,\n10,2,\n20,3,\n"))
    assert "column 'U': the column has no values" in message


def test_many_gaps_in_one_column_are_summarised_in_one_note(tmp_path: Path) -> None:
    """A sensor dropping every third sample gives one note, not one per gap."""
    data = load_data(write(tmp_path, series(30, cells={i: "" for i in range(1, 29, 3)})))
    assert data.notes == (
        "T_spindle_degC: 10 missing samples in 10 gaps interpolated (longest 15 s, first at 15 s)",
    )


def test_a_negative_max_gap_s_is_refused(tmp_path: Path) -> None:
    """max_gap_s is a duration: a negative value is a compd error, not a silent 'no gaps'."""
    assert "max_gap_s = -1" in refusal(write(tmp_path, series(5)), max_gap_s=-1)


# --- Parquet --------------------------------------------------------------------------------------


def test_parquet_loads_like_the_same_csv(tmp_path: Path) -> None:
    """A Parquet file with timestamps and a gap gives the values, start time and notes of a CSV."""
    pytest.importorskip("pyarrow")
    frame = pd.DataFrame(
        {
            "timestamp": pd.date_range("2024-01-05T10:00:00+01:00", periods=6, freq="15s"),
            "T_spindle_degC": [20.0, np.nan, 21.0, 21.5, 22.0, 22.5],
            "spindle_speed_rpm": [0, 3200, 3200, 3200, 6400, 6400],
        }
    )
    frame.to_parquet(tmp_path / "calib.parquet")
    data = load_data(tmp_path / "calib.parquet")
    assert data.start_time is not None
    assert data.start_time.utcoffset() == timedelta(hours=1)
    assert_array_equal(data.time_s, np.arange(6) * 15.0)
    assert_allclose(data.column("T_spindle_degC"), [20.0, 20.5, 21.0, 21.5, 22.0, 22.5])
    assert_array_equal(data.column("spindle_speed_rpm"), frame["spindle_speed_rpm"].to_numpy(float))
    assert data.notes == ("T_spindle_degC: 1 missing sample at 15 s interpolated",)


def test_a_bad_parquet_cell_names_its_row(tmp_path: Path) -> None:
    """Parquet has rows, not lines: the message names the data row (1-based)."""
    pytest.importorskip("pyarrow")
    pd.DataFrame({"time_s": [0.0, 1.0, 2.0], "T": ["1", "x", "3"]}).to_parquet(tmp_path / "bad.pq")
    assert "row 2, column 'T': 'x' is not a number" in refusal(tmp_path / "bad.pq")


def test_parquet_without_pyarrow_tells_how_to_install_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Without pyarrow, a Parquet file is refused with the pip command that adds it."""
    monkeypatch.setitem(sys.modules, "pyarrow", None)
    monkeypatch.setitem(sys.modules, "pyarrow.parquet", None)
    message = refusal(tmp_path / "calib.parquet")
    assert "pyarrow" in message
    assert "pip install 'compd[parquet]'" in message


# --- DataSet --------------------------------------------------------------------------------------


def test_an_absent_column_is_refused_listing_the_available_ones(tmp_path: Path) -> None:
    """column() names the file, the missing column and every column the file has."""
    path = write(tmp_path, series(5))
    with pytest.raises(DataFileError) as info:
        load_data(path).column("T_ram_degC")
    assert str(info.value) == (
        f"{path}: there is no column 'T_ram_degC'. "
        "Use one of the file's columns: 'T_spindle_degC', 'T_shopfloor_degC'"
    )


def test_the_loaded_arrays_are_read_only(tmp_path: Path) -> None:
    """A DataSet is frozen down to its arrays, so no consumer can change another's data."""
    data = load_data(write(tmp_path, series(5)))
    with pytest.raises(ValueError, match="read-only"):
        data.column("T_spindle_degC")[0] = 0.0
    with pytest.raises(ValueError, match="read-only"):
        data.time_s[0] = 1.0
    with pytest.raises(TypeError):
        data.columns["new"] = data.time_s  # type: ignore[index]


# --- property -------------------------------------------------------------------------------------


@st.composite
def gappy_series(draw: st.DrawFn) -> tuple[list[float], list[bool], list[bool]]:
    """Values on a 1 s grid, interior gaps, and per gap: row absent (True) or cell empty."""
    n = draw(st.integers(3, 40))
    values = draw(st.lists(st.floats(-1e3, 1e3, allow_subnormal=False), min_size=n, max_size=n))
    gaps = [False, *draw(st.lists(st.booleans(), min_size=n - 2, max_size=n - 2)), False]
    absent = draw(st.lists(st.booleans(), min_size=n, max_size=n))
    return values, gaps, absent


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.filter_too_much])
@given(case=gappy_series())
def test_interpolated_values_lie_between_their_neighbours_and_others_are_unchanged(
    tmp_path_factory: pytest.TempPathFactory, case: tuple[list[float], list[bool], list[bool]]
) -> None:
    """Filled samples lie within their neighbours' range; logged samples are read exactly."""
    values, gaps, absent = case
    n = len(values)
    kept = [i for i in range(n) if not (gaps[i] and absent[i])]
    assume(np.median(np.diff(kept)) == 1)  # otherwise the median step is not the 1 s grid
    lines = [f"{i},{'' if gaps[i] else repr(values[i])}" for i in kept]
    path = tmp_path_factory.getbasetemp() / "property.csv"
    path.write_text("time_s,y\n" + "\n".join(lines) + "\n")

    y = load_data(path, max_gap_s=n).column("y")

    assert_array_equal(y[~np.array(gaps)], np.array(values)[~np.array(gaps)])
    for i in np.flatnonzero(gaps):
        before = max(j for j in range(i) if not gaps[j])
        after = min(j for j in range(i + 1, n) if not gaps[j])
        low, high = sorted((values[before], values[after]))
        assert low - 1e-9 <= y[i] <= high + 1e-9


# --- bounded work on any input (issue 14, item 8) ----------------------------------------------


def test_a_nanosecond_step_is_refused_before_any_grid_is_made(tmp_path: Path) -> None:
    """A 59-byte file of 1e-9 s steps (a 15 GiB grid once) is refused for its sample time, naming the column."""
    path = write(tmp_path, "time_s,x\n0,1\n1e-9,2\n2e-9,3\n3e-9,4\n4e-9,5\n5e-9,4\n6e-9,3\n2,4\n")
    message = refusal(path)
    assert "column 'time_s': the median time step is 1e-09 s, outside 1e-06-86400 s" in message


@pytest.mark.parametrize("resample", [False, True], ids=["on_grid", "resampled"])
def test_a_grid_beyond_the_sample_limit_is_refused_before_it_is_made(
    tmp_path: Path, resample: bool
) -> None:
    """Six rows implying 50 million samples (1 us steps over 50 s) are refused naming the last line."""
    rows = "".join(f"{k}e-6,{k}\n" for k in range(5)) + "50,5\n"
    path = write(tmp_path, "time_s,x\n" + rows + ("50.0000015,6\n" if resample else ""))
    message = refusal(path, resample=resample)
    assert "column 'time_s': 50" in message
    assert "samples on a uniform grid: more than the limit of 20,000,000 samples" in message


def test_too_many_columns_are_refused_from_the_header(tmp_path: Path) -> None:
    """A header of 100,001 columns is refused on line 1 before the rows are parsed."""
    names = ",".join(f"c{i}" for i in range(100_000))
    path = write(
        tmp_path, f"time_s,{names}\n" + "".join(f"{t}{',1' * 100_000}\n" for t in range(3))
    )
    message = refusal(path)
    assert "line 1: the header names 100,001 columns, more than the limit of 1,000" in message


def test_a_header_line_beyond_the_limit_is_refused_unsplit(tmp_path: Path) -> None:
    """A header of 10^6 one-letter names (2 MB) is refused by its length before it is split."""
    path = write(tmp_path, "time_s" + ",x" * 1_000_000 + "\n0,1\n")
    assert "line 1: the header line is longer than 1,000,000 characters" in refusal(path)


def test_a_file_beyond_the_size_limit_is_refused_unread(tmp_path: Path) -> None:
    """A data file of more than 1 GiB (sparse here) is refused by its size, with the fix."""
    path = write(tmp_path, "time_s,x\n0,1\n1,2\n")
    with path.open("r+b") as handle:
        handle.truncate(2**30 + 1)
    message = refusal(path)
    assert "1,073,741,825 bytes, more than the limit of 1,073,741,824" in message
    assert "Split it" in message


def test_a_huge_cell_is_quoted_cut(tmp_path: Path) -> None:
    """A 5 MB bad cell is quoted by its first 40 characters and its length, not echoed whole."""
    path = write(tmp_path, "time_s,x\n0,1\n1," + "x" * 5_000_000 + "\n2,3\n")
    message = refusal(path)
    assert "line 3, column 'x': 'xxxx" in message and "... (5,000,000 characters) is not" in message
    assert len(message) - len(str(path)) < 250


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("0,1\n1,2\n2,3\n1e308,4\n", "1e+308 samples on a uniform grid"),
        ("-1e308,1\n0,2\n1e308,3\n", "time 1e308 s is too far from the first time -1e308 s"),
        ("0,1\n1e300,2\n2e300,3\n", "the median time step is 1e+300 s"),
    ],
    ids=["far_end", "beyond_float", "huge_step"],
)
def test_times_near_the_float_range_are_refused_in_short_messages(
    tmp_path: Path, text: str, expected: str
) -> None:
    """Times up to 1e308 s give a DataFileError of a few lines, never a traceback or 309 digits."""
    path = write(tmp_path, "time_s,x\n" + text)
    message = refusal(path)
    assert expected in message and len(message) - len(str(path)) < 250


def test_values_beyond_the_limit_are_refused_naming_the_cell(tmp_path: Path) -> None:
    """A value of 1e300 (its square overflows in every fit) is refused naming line and column."""
    message = refusal(write(tmp_path, series(cells={4: "1e300"})))
    assert "line 6, column 'T_spindle_degC': '1e+300' is beyond +-1e+15" in message
