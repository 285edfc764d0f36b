"""The terminal every command prints to (rich's console alone: a light import)."""

from __future__ import annotations

import sys

from rich.console import Console


def console() -> Console:
    """A console that does not wrap piped output at rich's 80-column default, and shows text as written.

    ``emoji=False``: rich would turn ``holding:100:int32`` into ``holding💯int32``
    (its ``:name:`` emoji codes); addresses, names and paths are printed literally.
    """
    # Piped output (a file, a CI log) is read by people and grep alike.
    return Console(highlight=False, emoji=False, width=None if sys.stdout.isatty() else 200)
