"""A plain data file read with the standard library and numpy: what the daemon replays without pandas.

The simulated driver (``type: simulated``, the bundled replay configs)
replays a logged record as live signals. :func:`compd.files.data.load_data`
reads any record (CSV or Parquet, gaps, irregular rows, timestamps) with
pandas, ~40 MB that a daemon otherwise never maps. Most replayed records are
plain: a ``time_s`` column, numbers in every cell, one row per sample time.
:func:`read_plain_csv` reads exactly those, giving what ``load_data`` gives
for them (times ``k * Ts`` from 0, the columns as written), and returns
None for anything else, which the caller hands to ``load_data``: its checks
and its messages stay the one way a record is judged.
"""

from __future__ import annotations

import csv
import math
import os
import statistics
import warnings
from pathlib import Path

import numpy as np

#: Larger files go to load_data (which refuses files past its own limit, naming it).
MAX_PLAIN_BYTES = 64 * 1024 * 1024
#: load_data's sample-time range (s), as :data:`compd.files.data.SAMPLE_TIME_RANGE_S`.
_SAMPLE_TIME_RANGE_S = (1e-6, 86_400.0)
#: A row further than this fraction of a step from its grid point is not plain.
_ON_GRID = 0.1


def read_plain_csv(path: str | os.PathLike[str]) -> tuple[np.ndarray, dict[str, np.ndarray]] | None:
    """``(time_s, columns)`` of a plain CSV record, or None where it is not plain (see the module).

    ``time_s`` is ``k * Ts`` from 0 (``Ts`` the median step to 9 significant
    digits, as ``load_data`` takes it); ``columns`` every other column by name.
    """
    path = Path(path)
    if path.suffix.lower() != ".csv" or not path.is_file():
        return None
    if path.stat().st_size > MAX_PLAIN_BYTES:
        return None
    try:
        with path.open(newline="", encoding="utf-8") as handle:
            header = [name.strip() for name in next(csv.reader([handle.readline()]), [])]
            if not header or header[0] != "time_s":
                return None
            # numpy's parser: no Python string per cell (a 185 kB record took 3 MB as rows
            # of strings, which a daemon replaying it kept as its peak memory).
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)  # no rows: refused below
                table = np.loadtxt(
                    handle, dtype=float, delimiter=",", comments=None, quotechar='"', ndmin=2
                )
    except (OSError, UnicodeDecodeError, csv.Error):
        return None
    except ValueError:  # a text cell, an empty one, or rows of different lengths
        return None
    if len(set(header)) != len(header) or any(not name for name in header):
        return None
    if table.shape[0] < 2 or table.shape[1] != len(header) or not np.all(np.isfinite(table)):
        return None
    time_s = table[:, 0]
    steps = np.diff(time_s)
    if np.any(steps <= 0):
        return None
    # statistics, not numpy's median: that one imports numpy.ma (1.3 MB) into the daemon.
    sample_time_s = float(f"{statistics.median(steps.tolist()):.9g}")
    low_s, high_s = _SAMPLE_TIME_RANGE_S
    if not (low_s <= sample_time_s <= high_s and math.isfinite(sample_time_s)):
        return None
    grid_s = np.arange(len(time_s)) * sample_time_s
    if np.any(np.abs(time_s - time_s[0] - grid_s) > _ON_GRID * sample_time_s):
        return None  # a missing or irregular row: load_data's grid and gap rules decide
    columns = {name: table[:, i].copy() for i, name in enumerate(header) if i > 0}
    return grid_s, columns
