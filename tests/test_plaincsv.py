"""A plain CSV record read without pandas gives what load_data gives; any other record is left to it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from compd.files.data import load_data
from compd.files.plaincsv import read_plain_csv

EXAMPLE = Path(__file__).parents[1] / "config" / "example_spectrum.csv"


def test_the_bundled_record_reads_as_load_data_reads_it() -> None:
    """Times from 0 on the grid, every column, the same numbers to the bit."""
    plain = read_plain_csv(EXAMPLE)
    assert plain is not None
    time_s, columns = plain
    data = load_data(EXAMPLE)
    np.testing.assert_array_equal(time_s, data.time_s)
    assert list(columns) == list(data.columns)
    for name, values in columns.items():
        np.testing.assert_array_equal(values, data.columns[name])


@pytest.mark.parametrize(
    "text",
    [
        "time_s,a\n0,1\n10,2\n30,3\n40,4\n",  # a missing row: load_data's gap rules
        "time_s,a\n0,1\n10,\n20,3\n",  # an empty cell
        "time_s,mode\n0,on\n10,off\n20,on\n",  # a text column
        "time,a\n0,1\n10,2\n20,3\n",  # another time column
        "time_s,a\n0,1\n20,2\n10,3\n",  # times out of order
        "time_s,a\n0,1\n",  # one row: no sample time
        "# run: 1\ntime_s,a\n0,1\n10,2\n",  # the recorder's metadata lines: load_data's
        "time_s,a\n0,1\n# a note\n10,2\n",  # a line that is no row
        "time_s,a\n0,1,2\n10,2\n",  # rows of different lengths
    ],
)
def test_a_record_that_is_not_plain_is_left_to_load_data(text: str, tmp_path: Path) -> None:
    """None, so the caller reads it with load_data, its checks and its messages."""
    path = tmp_path / "record.csv"
    path.write_text(text)
    assert read_plain_csv(path) is None


def test_a_parquet_record_is_left_to_load_data(tmp_path: Path) -> None:
    """Only CSV is read here."""
    path = tmp_path / "record.parquet"
    path.write_bytes(b"PAR1")
    assert read_plain_csv(path) is None
