"""A table at the terminal's width without a word of it cut: headers wrap between words, or rows stack.

rich shrinks a table wider than the terminal by taking columns down evenly,
and a column taken below its longest word ends in an ellipsis (``disp_z_…``,
``reducti…``) even where every word would fit. :func:`fit_table` gives each
column at least its longest word and shares the rest of the width by what
each would still use; where even the longest words do not fit side by side,
each row is printed as a list of (header, value) pairs (:func:`stacked`).
"""

from __future__ import annotations

from collections.abc import Iterable

from rich.console import Console, Group, RenderableType
from rich.measure import Measurement
from rich.table import Column, Table
from rich.text import Text


def fit_table(table: Table, out: Console) -> RenderableType:
    """``table`` as it fits ``out``'s width: unchanged if it fits, else narrower or stacked."""
    unbounded = out.options.update_width(100_000)
    natural = out.measure(table, options=unbounded).maximum
    if natural <= out.width:
        return table
    ranges = [_column_range(out, column) for column in table.columns]
    overhead = natural - sum(r.maximum for r in ranges)  # borders and padding
    room = out.width - overhead
    least = sum(r.minimum for r in ranges)
    if least > room:
        return stacked(table)
    widths = _shared(ranges, room)
    for column, width in zip(table.columns, widths, strict=True):
        column.width = width
        column.overflow = "fold"  # nothing left to cut: each is at least its longest word
    return table


def stacked(table: Table) -> RenderableType:
    """Each row as a two-column list, header: value, under the table's title (the narrowest layout)."""
    parts: list[RenderableType] = []
    if table.title:
        parts.append(Text(str(table.title), style="bold"))
    headers = [_one_line(column.header) for column in table.columns]
    for k, row in enumerate(zip(*(column.cells for column in table.columns), strict=True)):
        if k:
            parts.append(Text(""))  # a blank line between rows
        pairs = Table.grid(padding=(0, 1))
        pairs.add_column(style="bold", overflow="fold")
        pairs.add_column(overflow="fold")
        for header, cell in zip(headers, row, strict=True):
            pairs.add_row(header, cell)
        parts.append(pairs)
    return Group(*parts)


def _column_range(out: Console, column: Column) -> Measurement:
    """A column's content width: its longest word (minimum) and its longest line (maximum)."""
    cells: Iterable[RenderableType] = [column.header, *column.cells]
    measured = [Measurement.get(out, out.options.update_width(100_000), c) for c in cells]
    return Measurement(max(m.minimum for m in measured), max(m.maximum for m in measured))


def _shared(ranges: list[Measurement], room: int) -> list[int]:
    """Widths from each minimum up, the spare shared by what each column would still use."""
    widths = [r.minimum for r in ranges]
    spare = room - sum(widths)
    wants = [r.maximum - r.minimum for r in ranges]
    total = sum(wants)
    if total <= 0 or spare <= 0:
        return widths
    widths = [w + spare * want // total for w, want in zip(widths, wants, strict=True)]
    left = room - sum(widths)
    # What the rounding left, one column each, to those furthest from their natural width.
    by_need = sorted(range(len(ranges)), key=lambda i: widths[i] - ranges[i].maximum)
    for i in by_need[:left]:
        widths[i] += 1
    return [min(w, r.maximum) for w, r in zip(widths, ranges, strict=True)]


def _one_line(header: RenderableType) -> RenderableType:
    """A header written on several lines (``RMS\\nreduction``) as one, for the stacked list."""
    if isinstance(header, str):
        return " ".join(header.split())
    return header
