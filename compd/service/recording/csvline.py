"""One recorded CSV line: the row's UTC time stamp and its cells, as the CSV recorder writes them.

A row is written every tick, and a tick after a sleep runs with cold caches,
where each call costs several times what it costs back to back. So the
common row (floats and ints) is formatted by one ``%`` operation with a
format made once per row shape (:class:`LineFormats`), and the time stamp's
date and minute once a minute (:class:`Stamps`); both give exactly the text
of the plain way (``datetime.isoformat``, :func:`cell` per value), which
formats any other row.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from datetime import UTC, datetime

Cell = float | int | str

_QUOTED = re.compile(r'[,"\r\n]')


def cell(value: Cell) -> str:
    """A value as the recorder writes it: floats to 15 digits, bools 1/0, text quoted where needed."""
    if value is True or value is False:
        return "1" if value else "0"
    # 15 digits (recorder_marks.tidy says why); "%" is the quickest; + 0.0 turns -0.0 into 0.0.
    text = "%.15g" % (value + 0.0) if isinstance(value, float) else str(value)
    if isinstance(value, str) and _QUOTED.search(text):
        return '"' + text.replace('"', '""') + '"'
    return text


def stamp(now_s: float) -> str:
    """``2026-11-23T10:15:00.000+00:00``: ``now_s`` (s since the epoch) in UTC, to the millisecond."""
    return datetime.fromtimestamp(now_s, UTC).isoformat(timespec="milliseconds")


class Stamps:
    """:func:`stamp`, the date and minute formatted once a minute (the same text)."""

    def __init__(self) -> None:
        self._minute = -1
        self._prefix = ""

    def __call__(self, now_s: float) -> str:
        if not now_s >= 0.0:  # before 1970 (or NaN): the plain way
            return stamp(now_s)
        # datetime.fromtimestamp's rounding: to the microsecond, half to even (round()).
        whole = math.floor(now_s)
        us = round((now_s - whole) * 1e6)
        if us >= 1_000_000:
            whole, us = whole + 1, us - 1_000_000
        minute, second = divmod(whole, 60)
        if minute != self._minute:
            self._minute = minute
            self._prefix = datetime.fromtimestamp(minute * 60, UTC).strftime("%Y-%m-%dT%H:%M:")
        return f"{self._prefix}{second:02d}.{us // 1000:03d}+00:00"


class LineFormats:
    """Whole lines ``stamp,cell,cell...\\n`` (:func:`cell` of each value), one ``%`` each.

    A row of plain floats, ints and bools has a format made once for its
    types (``%.15g`` and ``%d``); ``-0`` cells (a negative zero) are then
    written ``0``, as :func:`cell` writes them. Any other row (text, numpy
    scalars) is formatted cell by cell.
    """

    def __init__(self) -> None:
        self._formats: dict[tuple[type, ...], str | None] = {}
        #: The last row's types and format: the next row's, as a rule (compared, not hashed).
        self._last: tuple[tuple[type, ...], str | None] = ((), None)

    def line(self, stamp_text: str, values: Sequence[Cell]) -> str:
        types = tuple(map(type, values))
        last_types, form = self._last
        if types != last_types:
            try:
                form = self._formats[types]
            except KeyError:
                form = self._formats[types] = _format(types)
            self._last = types, form
        if form is None:
            return stamp_text + "," + ",".join(map(cell, values)) + "\n"
        line = form % (stamp_text, *values)
        if ",-0," in line:  # twice: the first pass skips the second of two in a row
            line = line.replace(",-0,", ",0,").replace(",-0,", ",0,")
        if line.endswith(",-0\n"):
            line = line[:-3] + "0\n"
        return line


#: The ``%`` code of a type whose :func:`cell` is plain: ``%d`` of an int is ``str``, of a bool 1/0.
_CODES = {float: "%.15g", int: "%d", bool: "%d"}


def _format(types: tuple[type, ...]) -> str | None:
    codes = [_CODES.get(t) for t in types]
    if not codes or None in codes:
        return None
    return "%s," + ",".join(codes) + "\n"  # type: ignore[arg-type]
