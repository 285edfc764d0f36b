"""Formatting rules of the report's tables."""

from compd.report.tables import change_cell, clock, collapsed, table


def test_clock_is_hours_and_minutes_from_start() -> None:
    """Window spans read as H:MM from the record's start, rounded to the minute (as compare prints them)."""
    assert clock(0.0) == "0:00"
    assert clock(5429.0) == "1:30"
    assert clock(26 * 3600.0 + 59.0 * 60) == "26:59"


def test_change_is_coloured_by_what_better_means() -> None:
    """A higher fit or reduction and a lower residue are better; changes below the shown digits are neutral."""
    assert change_cell(60.0, 70.0, 1, "fit_percent") == '<span class="better">+10.0</span>'
    assert change_cell(3.0, 4.0, 2, "rms_um") == '<span class="worse">+1.00</span>'
    assert change_cell(3.0, 3.001, 2, "rms_um") == '<span class="same">+0.00</span>'
    assert change_cell(1.0, 2.0, 2, "mean_um") == '<span class="same">+1.00</span>'
    assert change_cell(None, 2.0, 2, "rms_um") == "n/a"


def test_long_tables_are_folded() -> None:
    """A table of more than ten rows is folded into a details element with a summary line."""
    short = table(["a"], [["1"]] * 10)
    long = table(["a"], [["1"]] * 11)
    assert collapsed(short, "rows") == short
    assert collapsed(long, "11 rows").startswith("<details><summary>11 rows</summary><table>")
