"""A data file's cells read as numbers: times in seconds, ISO-8601 timestamps, signal values.

:mod:`compd.files.data` reads a file into a pandas frame; this module turns
its time column into seconds from the first row (timestamps with UTC
offsets as absolute instants) and each signal column into float64 with NaN
for gaps. A cell that is neither a number nor a gap is refused with the
file, line and column (:class:`~compd.files.data_checks.Rows`). The work is
vectorised: bad cells are located by comparing arrays, never by looping over rows.
"""

from __future__ import annotations

from datetime import datetime

import numpy as np
import pandas as pd

from compd.files import data_checks as checks
from compd.files.columns import TIME_SECONDS

GAP_TEXTS = ("", "NaN", "nan")
"""Cell texts that mark a missing sample (a gap), as opposed to a bad cell."""
MAX_ABS_VALUE = 1e15
"""Largest magnitude of a logged value: no sensor logs more, and squares of larger
values (in fits and RMS figures) overflow or lose every digit of the signal."""

_OFFSET = r"(Z|[+-]\d{2}(?::?\d{2})?)\s*$"  # a UTC offset ending an ISO-8601 time of day
_CELL_FIX = "Fix the cell or leave it empty to mark a gap"
_TIME_FIX = "Every row needs a time: fill it in or delete the row"


def times(frame: pd.DataFrame, rows: checks.Rows) -> tuple[np.ndarray, datetime | None, list[str]]:
    """Seconds from the first row, the first row's absolute time, and notes.

    ``time_s`` may start anywhere (its first value is subtracted). Timestamps
    with UTC offsets are absolute instants, so a daylight-saving change
    (+01:00 to +02:00) is read correctly and noted; a mix of timestamps with
    and without an offset is ambiguous and refused.
    """
    name = rows.time_name
    cells = frame[name]
    notes: list[str] = []
    empty = cells.isna().to_numpy()
    if empty.any():
        raise rows.error(rows.where(int(np.argmax(empty)), name), "the time is empty", _TIME_FIX)
    if name == TIME_SECONDS:
        seconds = _as_float(cells)
        bad = ~np.isfinite(seconds)
        if bad.any():
            i = int(np.argmax(bad))
            cell = checks.quote(cells.iloc[i])
            raise rows.error(rows.where(i, name), f"{cell} is not a time in seconds", _TIME_FIX)
        start_time = None
        with np.errstate(over="ignore"):
            time_s = seconds - seconds[0]
        far = ~np.isfinite(time_s)
        if far.any():
            i = int(np.argmax(far))
            raise rows.error(
                rows.where(i, name),
                f"time {rows.label(i)} is too far from the first time {rows.label(0)} "
                "(the difference is beyond the range of a float)",
                "Give times in seconds from a nearby origin",
            )
    else:
        stamps, start_time, notes = _timestamps(rows, cells)
        time_s = (stamps - stamps.iloc[0]).dt.total_seconds().to_numpy(dtype=float)
    step = np.diff(time_s)
    if (step <= 0).any():
        i = int(np.argmax(step <= 0)) + 1
        how = "the same as" if step[i - 1] == 0 else "before"
        raise rows.error(
            rows.where(i, name),
            f"time {rows.label(i)} is {how} the time {rows.label(i - 1)} on {rows.where(i - 1)}",
            "Times must strictly increase: remove the repeated row or sort the rows by time",
        )
    return time_s, start_time, notes


def _timestamps(rows: checks.Rows, cells: pd.Series) -> tuple[pd.Series, datetime, list[str]]:
    name = rows.time_name
    if pd.api.types.is_datetime64_any_dtype(cells.dtype):  # Parquet can store real timestamps
        return cells, cells.iloc[0].to_pydatetime(), []
    text = cells.astype(str).str.strip()
    offsets = text.str.slice(10).str.extract(_OFFSET, expand=False)  # after YYYY-MM-DD
    aware = offsets.notna().to_numpy()
    if aware.any() and not aware.all():
        i = int(np.argmax(aware != aware[0]))
        raise rows.error(
            rows.where(i, name),
            f"timestamp {checks.quote(text.iloc[i])} {'has' if aware[i] else 'has no'} "
            f"UTC offset, unlike {checks.quote(text.iloc[0])} on {rows.where(0)}: mixed time zones",
            "Write every timestamp with its UTC offset (e.g. +01:00), or none",
        )
    stamps = pd.to_datetime(text, format="ISO8601", utc=bool(aware[0]), errors="coerce")
    bad = stamps.isna().to_numpy()
    if bad.any():
        i = int(np.argmax(bad))
        seconds = pd.to_numeric(text.iloc[i : i + 1], errors="coerce").notna().all()
        fix = (
            f"If the column holds seconds, name it {TIME_SECONDS!r}"
            if seconds
            else "Write times as ISO-8601, e.g. 2024-03-05T14:30:00 or 2024-03-05T14:30:00+01:00"
        )
        raise rows.error(
            rows.where(i, name), f"{checks.quote(text.iloc[i])} is not an ISO-8601 timestamp", fix
        )
    notes = []
    distinct = sorted({_utc_offset(o) for o in offsets.dropna().unique()})
    if len(distinct) > 1:
        notes.append(
            f"{name}: timestamps carry several UTC offsets ({', '.join(distinct)}), "
            "e.g. a daylight-saving change; they were read as absolute times"
        )
    return stamps, pd.Timestamp(text.iloc[0]).to_pydatetime(), notes


def _utc_offset(text: str) -> str:
    """``Z``, ``+01``, ``+0100`` and ``+01:00`` in one form (``+01:00``)."""
    digits = "+0000" if text == "Z" else text.replace(":", "").ljust(5, "0")
    return f"{digits[:3]}:{digits[3:]}"


def _is_number_dtype(cells: pd.Series) -> bool:
    kind = cells.dtype
    return pd.api.types.is_numeric_dtype(kind) and not pd.api.types.is_bool_dtype(kind)


def _as_float(cells: pd.Series) -> np.ndarray:
    """Numbers as float64, NaN for missing cells and for text that is not a number."""
    if not _is_number_dtype(cells):
        cells = pd.to_numeric(cells.astype(str).str.strip(), errors="coerce")
    numbers: np.ndarray = cells.to_numpy(dtype=float, na_value=np.nan)
    return numbers


def numbers(cells: pd.Series, rows: checks.Rows) -> np.ndarray:
    """A signal column as float64 with NaN for gaps; a bad or infinite cell is refused."""
    values = _as_float(cells)
    huge = np.abs(values) > MAX_ABS_VALUE  # inf included; NaN compares False
    if _is_number_dtype(cells):  # the parser already turned the gap texts into NaN
        bad = huge
    else:  # NaN is a gap only if the text says so (not for '1,5' or 'NA')
        gap = (cells.isna() | cells.astype(str).str.strip().isin(GAP_TEXTS)).to_numpy()
        bad = (np.isnan(values) | huge) & ~gap
        values = np.where(gap, np.nan, values)
    if bad.any():
        i = int(np.argmax(bad))
        more = f" ({bad.sum() - 1} more bad cells in this column)" if bad.sum() > 1 else ""
        what = (
            "not a finite number"
            if np.isinf(values[i])
            else f"beyond +-{MAX_ABS_VALUE:g}"
            if huge[i]
            else "not a number"
        )
        cell = checks.quote(str(cells.iloc[i]).strip())
        raise rows.error(rows.where(i, str(cells.name)), f"{cell} is {what}{more}", _CELL_FIX)
    return values
