"""A message's bytes judged before they are parsed, and parsed off the event loop in linear time.

A broker hands the daemon whatever a sender published. Before a byte of it is
parsed, its size is checked against its topic's bound (a model roll-out may
be 1.4 MB, a probe is a few hundred bytes: :class:`~compd.service.fleet.commands.Commands`)
and its nesting depth against :data:`MAX_DEPTH` (:func:`nesting_depth`: C-speed
passes over the bytes, no parse). Parsing (:class:`Parser`) runs in a worker
thread, one message at a time, so the 1 Hz tick never waits for it; every
step is linear in the payload's length (:func:`unread_number` walks the
parsed values once: a 500 kB JSON array took 30 s on the loop when it was
walked with ``list.pop(0)``, which is quadratic).

Numbers compd does not read (NaN, Infinity, 1e400, integers of more than
:data:`MAX_DIGITS` digits) parse as :class:`Unread`, so that a request
holding one is refused with an answer to its id rather than dropped unanswered.
"""

from __future__ import annotations

import asyncio
import json
import math
import re
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np

from compd.errors import CompdError

#: Deepest nesting of arrays and objects in a message: a request is one flat object (1), a
#: desired record too; the rest is room for fields a later version may add.
MAX_DEPTH = 8
#: The most digits of an integer in a request (its times have ten): more is corrupt, or an attack
#: on ``int()`` (Python converts at most 4,300 digits, and slowly).
MAX_DIGITS = 30
#: A request id is one topic level of the reply's topic: no wildcards, no separators.
REQUEST_ID = re.compile(r"^[A-Za-z0-9_.:-]{1,100}$")

# A JSON string, escapes included (the unrolled form: linear, no backtracking).
_STRINGS = re.compile(rb'"[^"\\]*(?:\\.[^"\\]*)*"', re.DOTALL)
_NOT_BRACKETS = bytes(b for b in range(256) if b not in b"[]{}")
_OPENS = np.zeros(256, dtype=np.int8)
_OPENS[list(b"[{")] = 1
_OPENS[list(b"]}")] = -1
_REQUEST_ID_KEY = b'"request_id"'
_ID_VALUE = re.compile(rb'\s*:\s*"([A-Za-z0-9_.:-]{1,100})"')

TOO_DEEP = (
    f"arrays or objects nested more than {MAX_DEPTH} deep (a request is one flat JSON object)"
)


def nesting_depth(payload: bytes) -> int:
    """The deepest nesting of ``[`` and ``{`` outside JSON strings (0: none); linear, at C speed.

    Strings are cut out with one regular expression, every byte but the four
    brackets deleted, and the depth is the running sum's maximum (``[`` and
    ``{`` count +1, ``]`` and ``}`` -1). Bytes that are not JSON give some
    number: the parse refuses them after.
    """
    brackets = _STRINGS.sub(b"", payload).translate(None, _NOT_BRACKETS)
    if not brackets:
        return 0
    steps = _OPENS[np.frombuffer(brackets, dtype=np.uint8)].astype(np.int64)
    return int(np.cumsum(steps).max())


def cheap_request_id(payload: bytes) -> str | None:
    """The ``request_id`` a payload names, read without parsing it; None unless named exactly once.

    For answering a message refused before (or instead of) its parse: too
    large, too deep, retained, not JSON. A payload that names the key more than
    once (inside a string, say) has no id read this way.
    """
    at = payload.find(_REQUEST_ID_KEY)
    if at < 0 or payload.find(_REQUEST_ID_KEY, at + 1) >= 0:
        return None
    match = _ID_VALUE.match(payload, at + len(_REQUEST_ID_KEY))
    return None if match is None else match.group(1).decode("ascii")


class Unread:
    """A number in a request that compd does not read (NaN, 1e400, 10^5000): refused once the id is known."""

    def __init__(self, why: str) -> None:
        self.why = why

    def __repr__(self) -> str:
        return self.why


def _yielding_int(text: str) -> int:
    """``int``, as a Python function: the interpreter may switch threads at each call (a C builtin would not)."""
    return int(text)


def _int(text: str) -> int | Unread:
    digits = len(text.lstrip("-"))
    return Unread(f"an integer of {digits} digits") if digits > MAX_DIGITS else int(text)


def _float(text: str) -> float | Unread:
    value = float(text)
    return value if math.isfinite(value) else Unread(f"{text[:40]} (beyond any float)")


def _constant(text: str) -> Unread:
    return Unread(f"{text} (not a finite number)")


def parse_object(payload: bytes, *, max_depth: int = MAX_DEPTH) -> dict[str, Any]:
    """A JSON object from ``payload``, nesting checked first; raises CompdError saying what is wrong.

    Linear in ``len(payload)``; a worker thread's work (:class:`Parser`).
    Numbers compd does not read parse as :class:`Unread` (:func:`unread_number`
    finds the first).
    """
    if nesting_depth(payload) > max_depth:
        raise CompdError(f"the request is not JSON compd reads: {TOO_DEEP}")
    try:
        value = json.loads(payload, parse_int=_int, parse_float=_float, parse_constant=_constant)
    except (UnicodeDecodeError, ValueError) as exc:  # json.JSONDecodeError is a ValueError
        raise CompdError(f"the request is not JSON ({str(exc)[:200]})") from exc
    except RecursionError as exc:  # not reached below MAX_DEPTH; a guard all the same
        raise CompdError(f"the request is not JSON compd reads: {TOO_DEEP}") from exc
    if not isinstance(value, dict):
        raise CompdError("the request is not a JSON object")
    return value


def unread_number(request: dict[str, Any]) -> str | None:
    """``key: why`` of the first number in ``request`` that compd does not read, else None.

    Breadth first, each value visited once (a deque, a key's path formed only
    for the one returned): linear in the values.
    """
    queue: deque[tuple[tuple[str | int, ...], Any]] = deque(((k,), v) for k, v in request.items())
    while queue:
        path, value = queue.popleft()
        if isinstance(value, Unread):
            key = str(path[0]) + "".join(
                f"[{p}]" if isinstance(p, int) else f".{p}" for p in path[1:]
            )
            return f"{key[:100]}: {value.why}"
        if isinstance(value, dict):
            queue.extend(((*path, k), v) for k, v in value.items())
        elif isinstance(value, list):
            queue.extend(((*path, i), v) for i, v in enumerate(value) if not _plain(v))
    return None


def _plain(value: Any) -> bool:
    """A value that is read as it is (a string, a finite number, a flag, null): nothing to walk."""
    return value is None or type(value) in (str, int, float, bool)


def record_or_none(payload: bytes, *, max_bytes: int, max_depth: int = MAX_DEPTH) -> Any:
    """A retained record's JSON (a birth, a death, a desired record), or None if over a bound or not JSON.

    For what paho's thread reads itself (no answer is owed): size and depth
    first, then one linear ``json.loads`` that calls Python for each number
    (:func:`_yielding_int`), so the event loop's thread gets its turns meanwhile.
    """
    if len(payload) > max_bytes or nesting_depth(payload) > max_depth:
        return None
    try:
        return json.loads(payload, parse_int=_yielding_int)
    except (UnicodeDecodeError, ValueError, RecursionError):
        return None


@dataclass(frozen=True)
class Parsed:
    """A message parsed: its object, and the first number in it compd does not read (None: none)."""

    value: dict[str, Any]
    unread: str | None


def parse_checked(payload: bytes, *, max_depth: int = MAX_DEPTH) -> Parsed:
    """:func:`parse_object` and :func:`unread_number` in one: a worker thread's whole work."""
    value = parse_object(payload, max_depth=max_depth)
    return Parsed(value, unread_number(value))


class Parser:
    """Parses messages in a worker thread, one at a time: the event loop only awaits the result.

    The thread's parse calls Python for each number (the hooks that find
    those compd does not read), so it gives the event loop its turn every few
    milliseconds (the interpreter's switch interval) however long the message.
    """

    def __init__(self, *, max_depth: int = MAX_DEPTH) -> None:
        self.max_depth = max_depth
        self._one = asyncio.Lock()

    async def parse(self, payload: bytes) -> Parsed:
        """:func:`parse_checked` of ``payload``, off the loop; raises CompdError as it does."""
        async with self._one:
            return await asyncio.to_thread(parse_checked, payload, max_depth=self.max_depth)
