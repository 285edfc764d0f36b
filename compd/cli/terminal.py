"""The terminal every command prints to (rich's console alone: a light import).

Text is printed as written: no emoji codes (``holding:100:int32`` stays itself,
not ``holding💯int32``) and no markup (a path or name holding ``[bold]`` or
``[/x]`` is shown, never eaten or a MarkupError). Styles are given as
:class:`rich.text.Text` (``Text.assemble(("ok", "green"), ": ", path)``).
"""

from __future__ import annotations

import os
import sys

from rich.console import Console
from rich.text import Text

__all__ = ["Text", "console", "console_at", "duration_text"]

#: Piped output's width when ``COLUMNS`` does not say: a file or a CI log is read by
#: people and grep alike, so not rich's 80 columns.
PIPED_WIDTH = 200


def console() -> Console:
    """A console that does not wrap piped output at rich's 80-column default, and shows text as written.

    An exported ``COLUMNS`` is the width asked for, piped or not (``COLUMNS=120
    compd diagnose ... | less``); rich reads it itself when ``width`` is ``None``.
    """
    piped = not sys.stdout.isatty() and not os.environ.get("COLUMNS", "").isdigit()
    return Console(highlight=False, emoji=False, markup=False, width=PIPED_WIDTH if piped else None)


def console_at(out: Console, width: int) -> Console:
    """A console writing where ``out`` writes, ``width`` columns wide (a ``--wide`` table's own)."""
    return Console(file=out.file, highlight=False, emoji=False, markup=False, width=width)


def duration_text(seconds: float) -> str:
    """A length of time as a person reads it: ``13 s``, ``12.5 min``, ``24.00 h``."""
    if seconds < 120.0:
        return f"{seconds:.0f} s"
    if seconds < 7200.0:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.2f} h"
