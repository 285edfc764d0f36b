"""Data files: logged machine signals read into one uniform, gap-free time series.

A model runs at one fixed sample time, so a logger's file (CSV, or Parquet)
is brought onto a uniform grid here, once: jitter is snapped, short gaps are
interpolated, irregular sampling is resampled only when asked to, and every
repair is reported in :attr:`DataSet.notes`. Anything that cannot be repaired
safely is refused with a :class:`~compd.errors.DataFileError` naming the file,
the line (the header is line 1), the column and the fix: a model fitted or
checked on silently patched data would be trusted for the wrong reasons.

Parsing is vectorised (pandas' C parser, ``pd.to_numeric``), so a week at
1 Hz (604,800 rows) loads in a second or two; this module reads the file and
its header, :mod:`compd.files.data_cells` turns the cells into numbers.

The work is bounded by the input: a file larger than :data:`MAX_FILE_BYTES`
or with more than :data:`MAX_COLUMNS` columns is refused before it is
parsed, and the grid's size before it is made (:mod:`compd.files.data_checks`).
"""

from __future__ import annotations

import csv
import itertools
import math
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from datetime import datetime
from types import MappingProxyType

import numpy as np
import pandas as pd

from compd.errors import DataFileError
from compd.files import data_checks as checks
from compd.files.columns import TIME_NAMES, TIME_SECONDS, TIMESTAMP_NAMES
from compd.files.data_cells import GAP_TEXTS, numbers, times

PARQUET_SUFFIXES = (".parquet", ".pq")

MAX_FILE_BYTES = 2**30
"""Largest data file read, 1 GiB: about 20 million rows of 5 signals at 1 Hz."""
MAX_COLUMNS = 1000
"""Most columns (time included) in a data file: a machine logs tens of signals, not thousands."""
MAX_HEADER_CHARS = 1_000_000
"""Longest header line: 1,000 names of up to 1,000 characters."""
SAMPLE_TIME_RANGE_S = (1e-6, 86_400.0)
"""The sample times a data file may have: from 1 us to one sample a day."""
_HEADER_FIX = "Start with a header row of short names, e.g. time_s,T_spindle_degC"


@dataclass(frozen=True, eq=False)  # eq=False: arrays have no single truth value
class DataSet:
    """Signals on a uniform time grid, without gaps, as read from one file.

    ``time_s[k] == k * sample_time_s``: seconds from the first sample.
    ``columns`` holds every signal (not the time column) as float64 arrays of
    ``len(time_s)`` values without NaN. The loader makes the arrays read-only,
    so a data set shared between computations cannot be changed by one of them.
    """

    path: str
    time_s: np.ndarray
    sample_time_s: float
    columns: Mapping[str, np.ndarray]
    start_time: datetime | None
    notes: tuple[str, ...]
    #: Where the rows come from, as the file says: ``machine_id``, ``compd_version``,
    #: ``model``, ``model_sha256``, ``config`` (CSV ``# key: value`` lines before the
    #: header; Parquet key-value metadata). Empty for a file that says nothing.
    metadata: Mapping[str, str] = field(default_factory=lambda: MappingProxyType({}))
    #: The files a record joined from one recorded run was read from, in order
    #: (:mod:`compd.files.runs`); empty for a record read from ``path`` alone.
    files: tuple[str, ...] = ()

    def __len__(self) -> int:
        return len(self.time_s)

    def column(self, name: str) -> np.ndarray:
        """One signal; an absent name is an error listing the columns the file has."""
        try:
            return self.columns[name]
        except KeyError:
            raise DataFileError(
                self.path,
                f"there is no column {checks.quote(name)}",
                fix=f"Use one of the file's columns: {', '.join(map(repr, self.columns))}",
            ) from None

    def has(self, name: str) -> bool:
        return name in self.columns


def load_data(
    path: str | os.PathLike[str], *, max_gap_s: float = 60.0, resample: bool = False
) -> DataSet:
    """Read a CSV or Parquet data file onto a uniform grid.

    The sample time ``Ts`` is the median time step. Rows within 10 % of ``Ts``
    of the grid point ``t0 + k * Ts`` are snapped to it and missing rows become
    gaps. Rows further off are refused unless ``resample``, which interpolates
    every column linearly onto the grid. A run of missing samples lasting at
    most ``max_gap_s`` (run length times ``Ts``) is interpolated linearly;
    longer runs, and runs at either end of a column, are refused.
    """
    path_text = os.fspath(path)
    if not (math.isfinite(max_gap_s) and max_gap_s >= 0):
        raise DataFileError(
            path_text,
            f"max_gap_s = {max_gap_s} is not a duration",
            fix="Give --max-gap-s (max_gap_s) as a number of seconds >= 0",
        )
    _check_file_size(path_text)
    reader = _read_parquet if path_text.lower().endswith(PARQUET_SUFFIXES) else _read_csv
    frame, rows, metadata = reader(path_text)
    signals = [name for name in frame.columns if name != rows.time_name]
    time_s, start_time, notes = times(frame, rows)
    values = np.vstack([numbers(frame[name], rows) for name in signals])
    sample_time_s = checks.median_step_s(time_s)
    low_s, high_s = SAMPLE_TIME_RANGE_S
    if not low_s <= sample_time_s <= high_s:
        raise rows.error(
            f"column {checks.quote(rows.time_name)}",
            f"the median time step is {checks.fmt_s(sample_time_s)} s, outside "
            f"{low_s:g}-{high_s:g} s",
            "Check the time column's unit: time_s is in seconds",
        )
    grid, row_s, grid_notes = checks.to_grid(
        rows, time_s, values, sample_time_s, max_gap_s=max_gap_s, resample=resample
    )
    notes += grid_notes
    notes += checks.fill_gaps(rows, signals, grid, row_s, sample_time_s, max_gap_s=max_gap_s)
    grid_s = np.arange(grid.shape[1]) * sample_time_s
    grid_s.flags.writeable = False
    grid.flags.writeable = False  # before the rows are taken, so every column is read-only
    columns = MappingProxyType(dict(zip(signals, grid, strict=True)))
    return DataSet(
        path_text,
        grid_s,
        sample_time_s,
        columns,
        start_time,
        tuple(notes),
        MappingProxyType(metadata),
    )


def _check_file_size(path: str) -> None:
    """Refuse a file beyond :data:`MAX_FILE_BYTES` before reading it (a missing one fails later)."""
    try:
        size = os.stat(path).st_size
    except OSError:
        return
    if size > MAX_FILE_BYTES:
        raise DataFileError(
            path,
            f"the file has {size:,} bytes, more than the limit of {MAX_FILE_BYTES:,} (1 GiB)",
            fix="Split it into shorter records (e.g. one file per day)",
        )


def _read_csv(path: str) -> tuple[pd.DataFrame, checks.Rows, dict[str, str]]:
    metadata: dict[str, str] = {}
    comments = 0  # "# key: value" lines before the header (the recorder's metadata)
    try:
        with open(path, encoding="utf-8-sig", newline="") as handle:
            # Bounded: a header of 10^8 short names would be a list of 10^8 strings.
            first = handle.readline(MAX_HEADER_CHARS + 1)
            while first.startswith("#") and len(first) <= MAX_HEADER_CHARS:
                key, colon, value = first[1:].partition(":")
                if colon and key.strip():
                    metadata[key.strip()] = value.strip()
                comments += 1
                first = handle.readline(MAX_HEADER_CHARS + 1)
            if len(first) > MAX_HEADER_CHARS:
                raise DataFileError(
                    path,
                    f"the header line is longer than {MAX_HEADER_CHARS:,} characters",
                    where=f"line {comments + 1}",
                    fix=_HEADER_FIX,
                )
            lines = itertools.chain([first], handle)  # a quoted name may span lines
            header = [name.strip() for name in next(csv.reader(lines), [])]
    except OSError as exc:
        raise DataFileError(path, f"cannot read the file ({exc.strerror})") from exc
    except UnicodeDecodeError as exc:
        raise DataFileError(
            path, f"is not a UTF-8 text CSV file ({exc})", fix="Export it as CSV in UTF-8"
        ) from exc
    except csv.Error as exc:  # e.g. a header cell longer than the csv module's field limit
        raise DataFileError(
            path,
            f"the header is not a CSV row ({exc})",
            where=f"line {comments + 1}",
            fix=_HEADER_FIX,
        ) from exc
    time_name = _check_header(path, header, f"line {comments + 1}")
    gap_texts = {name: [""] if name == time_name else list(GAP_TEXTS) for name in header}
    try:
        frame = pd.read_csv(
            path,
            header=0,
            skiprows=comments,
            names=header,
            index_col=False,
            encoding="utf-8-sig",
            dtype={time_name: str},
            keep_default_na=False,
            na_values=gap_texts,
            skip_blank_lines=False,  # keeps row i on line i + 2, so messages name real lines
        )
    except pd.errors.ParserError as exc:
        # The C parser counts file lines as we do: "Expected 9 fields in line 57, saw 10".
        found = re.search(r"Expected (\d+) fields in line (\d+), saw (\d+)", str(exc))
        where, what = (
            (f"line {found[2]}", f"{found[3]} cells, but the header names {found[1]}")
            if found
            else ("", f"not a well-formed CSV table ({str(exc).strip()})")
        )
        raise DataFileError(
            path, what, where=where, fix="Give every row as many cells as the header has names"
        ) from exc
    except (UnicodeDecodeError, ValueError) as exc:
        raise DataFileError(
            path, f"cannot be read as CSV ({exc})", fix="Export it as CSV in UTF-8"
        ) from exc
    places = frame.index.to_numpy() + 2 + comments
    blank = frame.isna().all(axis=1).to_numpy()
    if blank.any():  # blank lines carry no data; dropping them keeps the other rows' lines
        frame, places = frame[~blank], places[~blank]
    frame, rows = _with_rows(path, frame.reset_index(drop=True), time_name, places, "line")
    return frame, rows, metadata


def _read_parquet(path: str) -> tuple[pd.DataFrame, checks.Rows, dict[str, str]]:
    try:
        import pyarrow.parquet as pq
    except ImportError:
        raise DataFileError(
            path,
            "reading Parquet files needs pyarrow, which is not installed",
            fix="Install it: pip install 'compd[parquet]'",
        ) from None
    try:
        parquet = pq.ParquetFile(path)
        stored = parquet.schema_arrow.metadata or {}
        metadata = {
            key.decode(errors="replace"): value.decode(errors="replace")
            for key, value in stored.items()
            if not key.startswith(b"pandas") and key != b"ARROW:schema"
        }
        _check_header(path, [str(name).strip() for name in parquet.schema_arrow.names], "schema")
        frame = parquet.read().to_pandas()  # restores a stored pandas index as the index
        if any(name is not None for name in frame.index.names):
            frame = frame.reset_index()  # a named index (e.g. time_s) was a column to the writer
    except OSError as exc:  # pyarrow raises OSError for missing and unreadable files
        raise DataFileError(path, f"cannot read the file ({exc.strerror or exc})") from exc
    except ValueError as exc:  # pyarrow.ArrowInvalid: not Parquet, or a schema pandas cannot hold
        raise DataFileError(
            path,
            f"cannot be read as Parquet ({exc})",
            fix="Write it with pandas' DataFrame.to_parquet or pyarrow",
        ) from exc
    header = [str(name).strip() for name in frame.columns]
    time_name = _check_header(path, header, "schema")
    frame = frame.set_axis(header, axis=1).reset_index(drop=True)
    frame, rows = _with_rows(path, frame, time_name, np.arange(len(frame)) + 1, "row")
    return frame, rows, metadata


def _check_header(path: str, header: list[str], where: str) -> str:
    """Refuse unnamed, repeated and too many columns; return the name of the time column."""
    if len(header) > MAX_COLUMNS:
        raise DataFileError(
            path,
            f"the header names {len(header):,} columns, more than the limit of {MAX_COLUMNS:,}",
            where=where,
            fix="Keep the time and the signals a model needs (a file per group of signals)",
        )
    if not any(header):
        raise DataFileError(
            path,
            "there is no header row naming the columns",
            where=where,
            fix=f"Start with a header row, e.g. {TIME_SECONDS},T_spindle_degC",
        )
    for i, name in enumerate(header):
        if not name:
            raise DataFileError(
                path,
                f"column {i + 1} has no name",
                where=where,
                fix="Name every column in the header (or remove a trailing comma)",
            )
        first = header.index(name)
        if first != i:
            raise DataFileError(
                path,
                f"column {checks.quote(name)} appears twice (columns {first + 1} and {i + 1})",
                where=where,
                fix="Rename or remove one of them: every column needs a unique name",
            )
    found = [name for name in TIME_NAMES if name in header]
    if not found:
        raise DataFileError(
            path,
            f"no time column: expected one named {' or '.join(map(repr, TIME_NAMES))}; "
            f"the file has [{', '.join(map(checks.quote, header[:10]))}"
            + (f", and {len(header) - 10} more]" if len(header) > 10 else "]"),
            where=where,
            fix=f"Name the time column {TIME_SECONDS!r} (seconds) or one of "
            f"{', '.join(map(repr, TIMESTAMP_NAMES))} (ISO-8601 timestamps)",
        )
    if len(found) > 1:
        raise DataFileError(
            path,
            f"several time columns: {found}",
            where=where,
            fix="Keep one, or rename the others if they are signals",
        )
    if len(header) < 2:
        raise DataFileError(
            path,
            "there is no signal column besides the time",
            where=where,
            fix="Add at least one column of logged values",
        )
    return found[0]


def _with_rows(
    path: str, frame: pd.DataFrame, time_name: str, places: np.ndarray, unit: str
) -> tuple[pd.DataFrame, checks.Rows]:
    if len(frame) < 2:
        raise DataFileError(
            path,
            f"{len(frame)} data row(s); at least 2 are needed to find the sample time",
            fix="Check that this is the right file",
        )
    return frame, checks.Rows(path, places, unit, time_name, frame[time_name])
