"""The data loader's sampling rules: one uniform grid, gaps interpolated or refused.

:mod:`compd.files.data` reads a file into times (seconds from the first row) and
signals laid out as ``(n_columns, n_rows)``; this module puts them on the grid
``t_k = k * Ts`` and applies the gap rule, turning every refusal into a
message that names the file, the lines and the column (:class:`Rows` knows
where each row came from). The numerics are plain numpy functions.

The grid is sized before it is made: a few rows can imply billions of samples
(a 1e-9 s step and a 2 s span), so the implied sample count and the values it
would hold are checked against :data:`MAX_SAMPLES` and :data:`MAX_VALUES`
first, and every message quotes file text cut to :data:`QUOTE_CHARS`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from compd.errors import DataFileError

JITTER_FRACTION = 0.1
"""A row within this fraction of a sample time of a grid point is on the grid (logger jitter)."""

MAX_GAP_NOTES_PER_COLUMN = 5  # beyond this, a column's gaps are summarised in one note

_REL_TOL = 1e-9  # float noise in comparisons of times against limits

MAX_SAMPLES = 20_000_000
"""Samples on the grid, at most: 231 days at 1 Hz, 23 days at 10 Hz."""
MAX_VALUES = 200_000_000
"""Samples times signal columns on the grid, at most: 1.6 GB of float64."""
QUOTE_CHARS = 40
"""Longest file text (a cell, a column name, a time) quoted whole in a message."""


def quote(text: object) -> str:
    """``repr`` of file text for a message, cut to :data:`QUOTE_CHARS` characters (a 5 MB cell is not echoed)."""
    text = str(text)
    if len(text) <= QUOTE_CHARS:
        return repr(text)
    return f"{text[:QUOTE_CHARS]!r}... ({len(text):,} characters)"


@dataclass(frozen=True)
class Rows:
    """Where a file's rows are, for messages: each row's line (CSV, header = 1) or row (Parquet)."""

    path: str
    places: np.ndarray
    unit: str  # "line" or "row"
    time_name: str
    time_cells: pd.Series  # the time column as read, to quote times as the file wrote them

    def where(self, i: int, column: str | None = None) -> str:
        place = f"{self.unit} {self.places[i]}"
        return f"{place}, column {quote(column)}" if column else place

    def span(self, rows: slice) -> str:
        """The lines of ``rows`` (``lines 9-14``), or the two around an empty range."""
        start, stop, _ = rows.indices(len(self.places))
        if stop > start:
            first, last = self.places[start], self.places[stop - 1]
            return f"{self.unit} {first}" if first == last else f"{self.unit}s {first}-{last}"
        after = min(max(start, 1), len(self.places) - 1)
        return f"between {self.unit}s {self.places[after - 1]} and {self.places[after]}"

    def label(self, i: int) -> str:
        """Row ``i``'s time as written (with its unit for ``time_s``)."""
        cell = str(self.time_cells.iloc[i])
        if len(cell) > QUOTE_CHARS:
            cell = quote(cell)
        return f"{cell} s" if self.time_name == "time_s" else cell

    def error(self, where: str, message: str, fix: str = "") -> DataFileError:
        return DataFileError(self.path, message, where=where, fix=fix)


def median_step_s(time_s: np.ndarray) -> float:
    """The sample time: the median step of strictly increasing times, in s.

    The median ignores missing rows and outliers. It is rounded to 9
    significant digits so that float noise in the logged times (0.1 written
    as 0.09999999999999998) does not end up in the sample time models are
    compiled at.
    """
    return float(f"{np.median(np.diff(time_s)):.9g}")


def to_grid(
    rows: Rows,
    time_s: np.ndarray,
    values: np.ndarray,
    sample_time_s: float,
    *,
    max_gap_s: float,
    resample: bool,
) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Signals on the grid (NaN in gaps), each file row's time on it, and notes.

    A row within ``JITTER_FRACTION * Ts`` of a grid point is snapped to it;
    grid points no row fell on are gaps. Any row further off (or on the same
    grid point as the row before) makes the sampling irregular: refused, or
    with ``resample`` every column is interpolated onto the grid.
    """
    _check_grid_size(rows, time_s, sample_time_s, values.shape[0])
    k = np.rint(time_s / sample_time_s).astype(np.int64)
    off = np.abs(time_s - k * sample_time_s) > JITTER_FRACTION * sample_time_s * (1 + _REL_TOL)
    off[1:] |= np.diff(k) == 0
    irregular = bool(off.any())
    if irregular and not resample:
        i = int(np.argmax(off))
        if k[i] == k[i - 1]:
            what = f"is within 10 % of a sample of {rows.label(i - 1)} on {rows.where(i - 1)}"
        else:
            what = f"is {fmt_s(abs(time_s[i] - k[i] * sample_time_s))} s off the sampling grid"
        raise rows.error(
            rows.where(i, rows.time_name),
            f"time {rows.label(i)} {what}: irregular sampling "
            f"({off.sum()} of {len(time_s)} rows are more than 10 % of the {sample_time_s:g} s "
            "median step off the grid)",
            "Pass --resample (resample=True) to interpolate every "
            f"column onto a uniform {sample_time_s:g} s grid, or correct the times",
        )
    # Missing rows are a gap in every column: refuse a long one before making a grid for it.
    missing_s = np.diff(time_s) - sample_time_s if irregular else (np.diff(k) - 1) * sample_time_s
    long = _longer_than(missing_s, max_gap_s)
    if long.any():
        i = int(np.argmax(long))
        raise rows.error(
            rows.span(slice(i + 1, i + 1)),
            f"no rows for {fmt_s(missing_s[i])} s after "
            f"{rows.label(i)}, longer than max_gap_s = {max_gap_s:g} s",
            _gap_fix(max_gap_s),
        )
    if not irregular:
        grid = np.full((values.shape[0], int(k[-1]) + 1), np.nan)
        grid[:, k] = values
        return grid, k * sample_time_s, []
    grid = resample_linear(time_s, values, sample_time_s)
    note = (
        f"irregular sampling: {off.sum()} of {len(time_s)} rows were more than 10 % of the "
        f"median step off the grid; every column was linearly interpolated onto a uniform "
        f"{sample_time_s:g} s grid ({grid.shape[1]} samples)"
    )
    return grid, time_s, [note]


def _check_grid_size(rows: Rows, time_s: np.ndarray, sample_time_s: float, n_columns: int) -> None:
    """Refuse a grid of more than :data:`MAX_SAMPLES` samples or :data:`MAX_VALUES` values before making it."""
    samples = float(time_s[-1]) / sample_time_s + 1.0  # a float: it may be far beyond int64
    if samples <= MAX_SAMPLES and samples * n_columns <= MAX_VALUES:
        return
    limit = (
        f"more than the limit of {MAX_SAMPLES:,} samples"
        if samples > MAX_SAMPLES
        else f"{_count(samples * n_columns)} values with {n_columns} columns, more than the limit "
        f"of {MAX_VALUES:,}"
    )
    raise rows.error(
        rows.where(len(time_s) - 1, rows.time_name),
        f"{fmt_s(time_s[-1])} s of data at a sample time of {fmt_s(sample_time_s)} s "
        f"(the median step) make {_count(samples)} samples on a uniform grid: {limit}",
        "Check the time column's unit (seconds), or split the file into shorter records",
    )


def _count(n: float) -> str:
    """A count for messages: ``2,000,000,001``, or ``1e+308`` when digits would not help."""
    return f"{n:,.0f}" if n < 1e15 else f"{n:.3g}"


def resample_linear(time_s: np.ndarray, values: np.ndarray, sample_time_s: float) -> np.ndarray:
    """Linear interpolation of every column onto ``k * Ts`` for ``0 <= k * Ts <= time_s[-1]``.

    ``y(t_k) = (1 - w) y_i + w y_(i+1)`` with ``w = (t_k - t_i) / (t_(i+1) - t_i)``
    between the bracketing samples ``i, i+1``. A NaN (gap) in either
    bracketing sample gives NaN, unless the grid point falls exactly on the
    other one, so gaps carry over to the grid and go through the gap rule.
    """
    n = int(np.floor(time_s[-1] / sample_time_s * (1 + _REL_TOL))) + 1
    grid_s = np.arange(n) * sample_time_s
    i = np.clip(np.searchsorted(time_s, grid_s, side="right") - 1, 0, len(time_s) - 2)
    w = (grid_s - time_s[i]) / (time_s[i + 1] - time_s[i])
    left, right = values[:, i], values[:, i + 1]
    return np.where(w == 0, left, np.where(w == 1, right, (1 - w) * left + w * right))


def fill_gaps(
    rows: Rows,
    names: list[str],
    grid: np.ndarray,
    row_s: np.ndarray,
    sample_time_s: float,
    *,
    max_gap_s: float,
) -> list[str]:
    """Interpolate each column's gaps in place; refuse long gaps and gaps at the ends.

    A run of ``n`` missing samples is filled linearly between its neighbours
    if ``n * Ts <= max_gap_s``. Returns one note per gap (gaps shared by all
    columns, i.e. missing rows, in one note), or a summary per column that
    has many.
    """
    n = grid.shape[1]
    summaries: list[str] = []
    runs: dict[tuple[int, int], list[str]] = {}
    for name, values in zip(names, grid, strict=True):
        missing = np.isnan(values)
        if not missing.any():
            continue
        if missing.all():
            raise rows.error(
                f"column {quote(name)}",
                "the column has no values",
                "Fill it in, or delete the column",
            )
        starts, ends = gap_runs(missing)
        lengths = ends - starts
        refusal: tuple[int, str, str] | None = None
        long = _longer_than(lengths * sample_time_s, max_gap_s)
        if starts[0] == 0:
            refusal = (
                0,
                "at the start of the column cannot be interpolated",
                "Trim the file to start where every column has a value, or fill the cells",
            )
        elif ends[-1] == n:
            refusal = (
                -1,
                "at the end of the column cannot be interpolated",
                "Trim the file to end where every column has a value, or fill the cells",
            )
        elif long.any():
            i = int(np.argmax(long))
            refusal = (
                i,
                f"({fmt_s(lengths[i] * sample_time_s)} s) is longer than "
                f"max_gap_s = {max_gap_s:g} s",
                _gap_fix(max_gap_s),
            )
        if refusal:
            i, what, fix = refusal
            raise _gap_error(rows, name, (starts[i], ends[i]), row_s, sample_time_s, what, fix)
        values[:] = interpolate_gaps(values)
        if len(starts) > MAX_GAP_NOTES_PER_COLUMN:
            summaries.append(
                f"{name}: {lengths.sum()} missing samples in {len(starts)} gaps interpolated "
                f"(longest {fmt_s(lengths.max() * sample_time_s)} s, first at "
                f"{fmt_s(starts[0] * sample_time_s)} s)"
            )
        else:
            for run in zip(starts.tolist(), ends.tolist(), strict=True):
                runs.setdefault(run, []).append(name)
    notes = list(summaries)
    for (start, end), columns in sorted(runs.items()):
        who = "all columns" if len(columns) == len(names) > 1 else ", ".join(columns)
        notes.append(f"{who}: {_samples(start, end, sample_time_s)} interpolated")
    return notes


def gap_runs(missing: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Runs of True in a boolean vector as half-open index ranges ``[starts[i], ends[i])``."""
    edges = np.flatnonzero(np.diff(np.concatenate(([0], missing.astype(np.int8), [0]))))
    return edges[::2], edges[1::2]


def interpolate_gaps(values: np.ndarray) -> np.ndarray:
    """NaN samples replaced by linear interpolation between their valid neighbours.

    Works on sample indices (the grid is uniform); at the ends ``np.interp``
    would hold the edge value, which is why the caller refuses end gaps first.
    """
    missing = np.isnan(values)
    index = np.arange(len(values))
    filled = values.copy()
    filled[missing] = np.interp(index[missing], index[~missing], values[~missing])
    return filled


def fmt_s(seconds: float) -> str:
    """Seconds for messages: ``150``, ``0.3``, ``1e-09``, ``1e+308``; never ``0.30000000000000004``.

    Positional up to 10^9 s (``1.5e+05`` reads worse than ``150000``), powers of
    ten beyond and below 1 us, so a time of 1e308 s is not 309 digits long.
    """
    value = float(seconds)
    if value != 0 and not 1e-6 <= abs(value) < 1e9:
        return f"{value:.6g}"
    return np.format_float_positional(round(value, 6), trim="-")


def _longer_than(duration_s: np.ndarray, limit_s: float) -> np.ndarray:
    """``duration_s > limit_s``, ignoring float noise (3 * 20 s is not longer than 60 s)."""
    return np.asarray(duration_s) > limit_s * (1 + _REL_TOL) + 1e-12


def _gap_error(
    rows: Rows,
    name: str,
    run: tuple[int, int],
    row_s: np.ndarray,
    sample_time_s: float,
    what: str,
    fix: str,
) -> DataFileError:
    start, end = run
    # The file rows strictly between the valid samples either side of the gap.
    low = int(np.searchsorted(row_s, (start - 1) * sample_time_s, side="right"))
    high = int(np.searchsorted(row_s, end * sample_time_s, side="left"))
    return rows.error(
        f"{rows.span(slice(low, high))}, column {quote(name)}",
        f"a gap of {_samples(start, end, sample_time_s)} {what}",
        fix,
    )


def _gap_fix(max_gap_s: float) -> str:
    return (
        f"Fill in or cut out the missing data, or raise the limit (--max-gap-s, now "
        f"{max_gap_s:g} s) if interpolating across it is acceptable"
    )


def _samples(start: int, end: int, sample_time_s: float) -> str:
    """``3 missing samples at 120-150 s`` for grid indices ``[start, end)``."""
    count = end - start
    span = fmt_s(start * sample_time_s)
    if count > 1:
        span += f"-{fmt_s((end - 1) * sample_time_s)}"
    return f"{count} missing sample{'s' if count > 1 else ''} at {span} s"
