"""``compd diagnose``'s candidate table, laid out for the terminal it is printed on.

As ``compare``'s failing-windows table (:func:`compd.cli.evaluate.windows_table`):
a table that fits whole is shown whole, one line per candidate. Otherwise no cell
is cut (rich squeezing a table writes ``spin…``, ``-5.…``): the columns that
carry detail go first, from the least read (the sign, which the gain already
carries, then the cross-correlation's lag and its bound, the chance level, the
gain, the time constant, the error removed), named under the table; headers wrap
between words, numbers and signal names stay whole on one line, and the effect's
description takes what width is left, wrapped between its words. That fits 80
columns; on a narrower terminal rich squeezes what is left. ``--wide`` shows
every column whole, however wide.
"""

from __future__ import annotations

from rich.table import Table
from rich.text import Text

from compd.cli.terminal import duration_text
from compd.toolkit.analysis import DiagnosisResult
from compd.toolkit.summary import fmt

__all__ = ["diagnosis_table", "table_width"]

#: Every column, left to right.
_HEADS = (
    "rank",
    "signal",
    "effect",
    "explained %",
    "chance %",
    "held-out fit % with it",
    "error removed %",
    "time constant",
    "gain (um/unit)",
    "sign",
    "xcorr lag",
    "|xcorr| / 99 % bound",
    "significant",
)
#: The columns left out for width, first to last; the others are always shown.
_DROPPED_FIRST = (
    "sign",
    "xcorr lag",
    "|xcorr| / 99 % bound",
    "chance %",
    "gain (um/unit)",
    "time constant",
    "error removed %",
)
#: Cells that may wrap between words in the narrow layout (the others keep their one line;
#: every header wraps between its words).
_WRAPPED = {"effect", "held-out fit % with it", "error removed %", "time constant"}


def diagnosis_table(
    model_name: str, data_path: str, result: DiagnosisResult, top: int, *, width: int | None
) -> Table:
    """The ``top`` candidates, best first; ``width`` the terminal's, ``None`` for every column whole."""
    d = result.diagnosis
    rows: list[list[str]] = []
    significant: list[bool] = []
    for rank, c in enumerate(d.candidates[:top], start=1):
        cells = (
            str(rank),
            c.signal,
            result.effects[c.signal],
            fmt(c.explained_percent, 1),
            fmt(c.chance_percent, 1),
            _extended_cell(result, c.signal),
            _removed_cell(result, c.signal),
            " + ".join(duration_text(t) for t in c.time_constants_s),
            f"{c.gain_um_per_unit:.4g}",
            "+" if c.sign > 0 else "-",
            duration_text(c.lag_s),
            f"{abs(c.xcorr_peak):.2f} / {fmt(c.xcorr_bound)}",
            "yes" if c.significant else "no",
        )
        rows.append(list(cells))
        significant.append(c.significant)
    title = (
        f"{model_name} vs {data_path}: what explains the residue of {result.output} "
        f"(held-out explained share of its RMS, {d.residue_rms_um:.2f} um)"
    )
    shown = list(_HEADS)
    whole = _widths(shown, rows, narrow=False)
    if width is None or _width_of(whole) <= width:
        return _table(title, shown, rows, significant, whole, narrow=False)
    dropped: list[str] = []
    for head in _DROPPED_FIRST:
        if _width_of(_widths(shown, rows, narrow=True)) <= width:
            break
        shown.remove(head)
        dropped.append(head)
    # The room left goes to the effect's description, then to the columns from the
    # left, each up to its one-line width (a header on one line).
    widths = _widths(shown, rows, narrow=True)
    one_line = _widths(shown, rows, narrow=False)
    effect = shown.index("effect")
    for k in [effect, *range(len(shown))]:
        room = width - _width_of(widths)
        widths[k] = max(widths[k], min(one_line[k], widths[k] + room))
    table = _table(title, shown, rows, significant, widths, narrow=True)
    if dropped:
        table.caption = f"left out for width: {', '.join(dropped)}; --wide shows all"
    return table


def table_width(table: Table) -> int:
    """Terminal columns ``table`` takes: what ``--wide`` prints it at."""
    return sum((c.width or 0) + 3 for c in table.columns) + 1


def _widths(shown: list[str], rows: list[list[str]], *, narrow: bool) -> list[int]:
    """Each shown column's width: its longest cell, or (narrow) its longest word where it may wrap."""
    widths = []
    for head in shown:
        k = _HEADS.index(head)
        cells = [row[k] for row in rows]
        if narrow:
            words = [w for cell in [head, *cells] if head in _WRAPPED for w in cell.split()]
            whole = [] if head in _WRAPPED else cells
            widths.append(max([len(w) for w in head.split()] + [len(w) for w in words + whole]))
        else:
            widths.append(max(len(cell) for cell in [head, *cells]))
    return widths


def _width_of(widths: list[int]) -> int:
    return sum(widths) + 3 * len(widths) + 1  # 2 padding + 1 border per column


def _table(
    title: str,
    shown: list[str],
    rows: list[list[str]],
    significant: list[bool],
    widths: list[int],
    *,
    narrow: bool,
) -> Table:
    table = Table(title=title)
    for head, least in zip(shown, widths, strict=True):
        # Narrow, every header wraps between its words; the widths keep the other cells whole.
        table.add_column(head, width=least, no_wrap=not narrow)
    for row, yes in zip(rows, significant, strict=True):
        cells = [row[_HEADS.index(head)] for head in shown]
        last = Text(cells[-1], style="green") if yes else cells[-1]
        table.add_row(*cells[:-1], last)
    return table


def _extended_cell(result: DiagnosisResult, signal: str) -> str:
    held = result.extended.get(signal)
    return "-" if held is None else f"{held.before:.1f} -> {held.after:.1f}"


def _removed_cell(result: DiagnosisResult, signal: str) -> str:
    held = result.extended.get(signal)
    if held is None:
        return "-"
    mark = "" if held.accepted else " (refused)"
    return f"{held.error_removed_percent:.0f} ({held.folds_improved}/{held.n_folds} folds){mark}"
