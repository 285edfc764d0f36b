"""The terminal every command prints to (rich's console alone: a light import).

Text is printed as written: no emoji codes (``holding:100:int32`` stays itself,
not ``holding💯int32``) and no markup (a path or name holding ``[bold]`` or
``[/x]`` is shown, never eaten or a MarkupError). Styles are given as
:class:`rich.text.Text` (``Text.assemble(("ok", "green"), ": ", path)``).
"""

from __future__ import annotations

import sys

from rich.console import Console
from rich.text import Text

__all__ = ["Text", "console"]


def console() -> Console:
    """A console that does not wrap piped output at rich's 80-column default, and shows text as written."""
    # Piped output (a file, a CI log) is read by people and grep alike.
    width = None if sys.stdout.isatty() else 200
    return Console(highlight=False, emoji=False, markup=False, width=width)
