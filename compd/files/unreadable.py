"""Files the daemon cannot read: their numbers checked as they are read, and the files set aside; atomic writes.

The daemon's own files (the saved state, the installed models, the roll-out
ids) are written by the daemon, so a number that is not finite, out of its
range or thousands of digits long means a corrupt file (a bad card, a hand
edit, a disk that lied), never a value to run with. :func:`json_int` keeps
``json`` from building such an integer (Python's ``int()`` refuses more than
4,300 digits with a ValueError, and takes quadratic time below that);
:func:`finite` and :func:`whole` check a value as it is read, naming the key.
:func:`set_aside` renames a file that cannot be read, so that it no longer
stops a start while it stays there for a post-mortem: nothing is deleted.
:func:`write_atomic` replaces a file so that a crash leaves the old one or
the new one, never half of one.

Here, below the service, so that the file formats of the state directory
(:mod:`compd.files.probestate`) use them as the daemon's store does.
"""

from __future__ import annotations

import math
import os
import tempfile
import time
from pathlib import Path

from compd.files.yamlplace import shorten

#: The most digits of an integer read from the daemon's files (a tick counter has a few).
MAX_DIGITS = 30


class _Huge(float):
    """An integer of more than :data:`MAX_DIGITS` digits: infinite to arithmetic, and says what it was."""

    why = ""


def json_int(text: str) -> int | float:
    """``json.loads``'s ``parse_int``: an integer of more than :data:`MAX_DIGITS` digits is infinite."""
    digits = len(text.lstrip("-"))
    if digits <= MAX_DIGITS:
        return int(text)
    huge = _Huge("-inf" if text.startswith("-") else "inf")
    huge.why = f"an integer of {digits} digits"
    return huge


def finite(value: object, key: str, low: float = -math.inf, high: float = math.inf) -> float:
    """``value`` as a finite float in ``[low, high]``; ValueError naming ``key`` and what is wrong."""
    if isinstance(value, _Huge):
        raise ValueError(f"{key} is {value.why}")
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"{key} is {shorten(value)}, not a number")
    try:
        number = float(value)
    except OverflowError:  # an int beyond any float (json_int keeps them from a file)
        raise ValueError(f"{key} is an integer beyond any float") from None
    if not math.isfinite(number):
        raise ValueError(f"{key} is {number}, not a finite number")
    if not low <= number <= high:
        raise ValueError(f"{key} = {number:g} is beyond [{low:g}, {high:g}]")
    return number


def whole(value: object, key: str, low: int, high: int) -> int:
    """:func:`finite`, and a whole number."""
    number = finite(value, key, low, high)
    if number != int(number):
        raise ValueError(f"{key} = {number:g} is not a whole number")
    return int(number)


def set_aside(path: Path, now_unix_s: float | None = None) -> Path:
    """Rename ``path`` to ``<name>.corrupt-<UTC time>`` beside it (numbered if taken); raises OSError."""
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime(now_unix_s))
    target = path.with_name(f"{path.name}.corrupt-{stamp}")
    number = 1
    while target.exists():
        number += 1
        target = path.with_name(f"{path.name}.corrupt-{stamp}-{number}")
    os.replace(path, target)
    return target


def write_atomic(path: Path, content: bytes) -> None:
    """Replace ``path`` with ``content``: temp file in the same directory, fsync, rename, fsync dir."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(content)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    directory = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(directory)
    finally:
        os.close(directory)
