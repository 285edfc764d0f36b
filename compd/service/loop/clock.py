"""Clocks for the loop: real time (optionally scaled) and virtual time for tests.

The loop never reads time itself; it is handed a :class:`Clock`.
:class:`RealClock` follows the monotonic clock, optionally ``time_scale``
times faster (``compd run --time-scale`` on a simulated machine);
:class:`VirtualClock` jumps straight to each deadline, so tests replay an
8-hour shift in seconds through exactly the code a machine runs. ``wall()``
is the UTC time stamped on records and saved states: on a scaled or virtual
clock it runs with the clock, so a replay's records are spaced by the period.
"""

from __future__ import annotations

import asyncio
import time
from typing import Protocol

#: The last part of a real sleep taken with ``time.sleep`` for a precise wake-up (s).
FINE_S = 0.002


class Clock(Protocol):
    """Seconds: ``now()`` monotonic, ``wall()`` UTC epoch, ``sleep_until(t)`` in ``now()`` time."""

    def now(self) -> float: ...

    def wall(self) -> float: ...

    def wall_at(self, t: float) -> float:
        """The UTC epoch time (s) of clock time ``t``: ticks are stamped with their deadline."""
        ...

    async def sleep_until(self, t: float) -> None: ...


class RealClock:
    """The event loop's monotonic clock, running ``time_scale`` times faster than real time."""

    def __init__(self, time_scale: float = 1.0) -> None:
        if not time_scale > 0:
            raise ValueError(f"time_scale must be > 0, got {time_scale}")
        self.time_scale = time_scale
        self._t0 = time.monotonic()
        self._wall0 = time.time()

    def now(self) -> float:
        return (time.monotonic() - self._t0) * self.time_scale

    def wall(self) -> float:
        return self._wall0 + self.now()

    def wall_at(self, t: float) -> float:
        return self._wall0 + t

    async def sleep_until(self, t: float) -> None:
        """Sleep on the event loop until ``FINE_S`` before ``t``, then the rest in ``time.sleep``.

        The event loop waits in ``epoll``, whose timeout has 1 ms resolution
        and is rounded up: ticks would start 0.5-1 ms late on average. The
        last ``FINE_S`` are slept with ``time.sleep`` (``clock_nanosleep``,
        tens of microseconds of slack), blocking the loop for at most that
        long a tick, which nothing else on the loop needs then.
        """
        delay_s = (t - self.now()) / self.time_scale
        if delay_s > FINE_S:
            await asyncio.sleep(delay_s - FINE_S)
        remaining_s = (t - self.now()) / self.time_scale
        if remaining_s > 0:
            time.sleep(remaining_s)


class VirtualClock:
    """Time that jumps to every deadline at once: no real sleeping, fully deterministic."""

    def __init__(self, start_s: float = 0.0, wall0_unix_s: float = 1_700_000_000.0) -> None:
        self.t = start_s
        self.wall0_unix_s = wall0_unix_s

    def now(self) -> float:
        return self.t

    def wall(self) -> float:
        return self.wall0_unix_s + self.t

    def wall_at(self, t: float) -> float:
        return self.wall0_unix_s + t

    def advance(self, seconds: float) -> None:
        self.t += seconds

    async def sleep_until(self, t: float) -> None:
        self.t = max(self.t, t)
        await asyncio.sleep(0)  # let background tasks (reconnects, control requests) run
