"""What a recording's file says about itself beyond its rows: its run, its columns' units, its numbers.

The recorder rotates files, but the machine runs on; :mod:`compd.files.runs`
joins the files of one run back into one record for the toolkit, and it can
only do that if every file says which run it belongs to and which file came
before it. :class:`RunMarks` keeps that account for one recorder (one daemon
start: one run) and gives each new file its ``run_*`` keys and the units of
its columns; :func:`tidy` is how a recording stores a number.
"""

from __future__ import annotations

import math
import uuid
from collections.abc import Callable, Mapping
from pathlib import Path

import numpy as np
import numpy.typing as npt

from compd.files.columns import RUN_FILE, RUN_GAP_S, RUN_ID, RUN_PREVIOUS, RUN_REASON, UNIT_PREFIX

#: A column's unit, or None to say nothing about it.
Units = Callable[[str], str | None]


class RunMarks:
    """The run a recorder's files belong to: its id, how many files so far, the last one's name.

    ``why`` is set by the recorder when it starts a new file for a reason the
    times and columns do not show (``model``: the active model changed;
    ``resumed``: after a failed write; ``reopened``: on SIGHUP); ``units`` names
    each column's unit.
    """

    def __init__(self, units: Units | None = None) -> None:
        #: Generated once per recorder, i.e. per daemon start: a restart is a new run.
        self.run_id = uuid.uuid4().hex
        self.units = units
        self.why: str | None = None
        self._files = 0
        self._previous: str | None = None
        self._previous_columns: tuple[str, ...] = ()

    def file_metadata(
        self,
        metadata: Mapping[str, str],
        path: Path,
        columns: tuple[str, ...],
        *,
        now_s: float,
        last_s: float,
    ) -> dict[str, str]:
        """``metadata`` plus the ``run_*`` and ``unit.*`` keys of the new file ``path`` (first row at ``now_s``).

        ``last_s`` is the previous file's last row's time (s since the epoch).
        """
        if self._files == 0:
            reason = "start"
        elif now_s <= last_s:
            reason = "clock"
        elif self.why is not None:
            reason = self.why
        elif columns != self._previous_columns:
            reason = "columns"
        else:
            reason = "rotated"
        self._files += 1
        marks = {RUN_ID: self.run_id, RUN_FILE: str(self._files), RUN_REASON: reason}
        if self._previous is not None:
            marks[RUN_PREVIOUS] = self._previous
            marks[RUN_GAP_S] = repr(tidy(now_s - last_s))
        units = {}
        if self.units is not None:
            units = {f"{UNIT_PREFIX}{c}": u for c in columns if (u := self.units(c)) is not None}
        self._previous, self._previous_columns, self.why = path.name, columns, None
        return {**metadata, **marks, **units}


def tidy(value: float) -> float:
    """A number as a recording stores it: rounded to 15 significant digits, never ``-0.0``.

    15 digits is what a double holds faithfully (DBL_DIG): every decimal of up
    to 15 digits survives the round trip through a double, so a value meant as
    ``21.15`` (a register of 2115 counts times 0.01) is stored as the double
    nearest 21.15 and written ``21.15`` (Python's shortest round-trip repr),
    not ``21.150000000000002``, its product's binary rounding. What is dropped
    lies below 1e-15 of the value, far below any sensor's resolution.
    """
    if not math.isfinite(value):
        return value  # nan (a gap to the loader), inf, -inf
    return float(f"{value:.15g}") + 0.0  # + 0.0: -0.0 becomes 0.0


#: Where :func:`tidy_array` rounds: 10**k is exact for k <= 22, so |x| >= 1e-8 with 15 digits;
#: at 1e15 and above a double holds no fraction worth tidying.
_TIDY_RANGE = (1e-8, 1e15)


def tidy_array(values: npt.ArrayLike) -> np.ndarray:
    """:func:`tidy` for a column of values at once, as quick as numpy (the Parquet recorder's rows).

    ``round(x * 10**k) / 10**k`` with ``k = 14 - floor(log10 |x|)``: an
    integer below 2**53 divided by an exact power of ten is the double
    nearest a decimal of 15 significant digits, so it prints short (21.15).
    Where ``x`` lies half-way between two such decimals the product's
    rounding may pick the other one: a change in the 15th digit. Values
    outside :data:`_TIDY_RANGE` are kept as they are, NaN too.
    """
    x = np.asarray(values, dtype=float)
    size = np.abs(x)
    inside = (size >= _TIDY_RANGE[0]) & (size < _TIDY_RANGE[1])  # False for NaN and inf
    scale = 10.0 ** (14 - np.floor(np.log10(np.where(inside, size, 1.0))))
    return np.where(inside, np.round(x * scale) / scale, x) + 0.0
