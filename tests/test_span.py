"""Times and spans of a record: what ``--from``/``--until`` accept and which samples they select."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from compd.errors import DataFileError
from compd.files.data import load_data
from compd.toolkit.span import parse_time_s, resolve_span, until_stop


@pytest.mark.parametrize(
    ("text", "seconds"),
    [("7200", 7200.0), ("1800.5", 1800.5), ("32:06", 115560.0), ("0:01:30", 90.0)],
)
def test_times_are_seconds_or_hours_and_minutes(text: str, seconds: float) -> None:
    """A time is seconds from the record's first sample, or h:m[:s]."""
    assert parse_time_s(text) == seconds


@pytest.mark.parametrize("text", ["32h", "-5", "1:75", "inf", ""])
def test_anything_else_is_refused_with_the_accepted_forms(text: str) -> None:
    """A negative number, a unit or a minute of 75 is not a time; the message shows what is."""
    with pytest.raises(ValueError, match="hours:minutes"):
        parse_time_s(text)


@pytest.fixture
def record(tmp_path: Path):
    """100 samples at 10 s whose time column starts at 1000 s (the loader counts from the first)."""
    path = tmp_path / "r.csv"
    pd.DataFrame({"time_s": 1000.0 + 10.0 * np.arange(100), "T1": np.arange(100.0)}).to_csv(
        path, index=False
    )
    return load_data(path)


def test_a_span_holds_the_samples_from_from_until_before_until(record) -> None:
    """``[from, until)`` in seconds from the first sample; a time between samples rounds to the nearer."""
    span = resolve_span(record, 100.0, 504.0)
    assert (span.start, span.stop) == (10, 50)
    assert until_stop(record, span).column("T1")[-1] == 49.0
    whole = resolve_span(record, None, None)
    assert whole.whole and (whole.start, whole.stop) == (0, 100)
    assert until_stop(record, whole) is record


def test_a_window_past_the_end_names_the_records_span(record) -> None:
    """``--until`` beyond the last sample is an error giving the record's length."""
    with pytest.raises(DataFileError, match=r"--until.*outside the record.*0 \.\. 0:16:40"):
        resolve_span(record, None, 2000.0)
