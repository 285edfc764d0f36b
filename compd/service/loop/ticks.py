"""The scheduler: a tick every ``period_s`` on absolute deadlines, on an injectable clock.

:func:`run_periodic` wakes at ``t0 + k * period_s`` -- the next deadline is
the last one plus the period, never "now plus the period", so the loop does
not drift. A tick that ends after the next deadline is an overrun: the
missed deadlines are counted, logged and skipped (a late tick is not made up
by a burst of ticks).

The clock is injected (:mod:`compd.service.loop.clock`): real time, optionally
scaled, or virtual time that jumps straight to each deadline, so tests
replay an 8-hour shift in seconds through exactly the code a machine runs.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Awaitable, Callable
from dataclasses import dataclass

import structlog

from compd.service.loop.clock import Clock

log = structlog.get_logger("compd.service.loop.ticks")


@dataclass
class TickTiming:
    """Scheduler counters: ticks run, deadlines missed, lateness of the wake-ups (s)."""

    ticks: int = 0
    overruns: int = 0
    last_lateness_s: float = 0.0
    max_lateness_s: float = 0.0


async def run_periodic(
    clock: Clock,
    period_s: float,
    tick: Callable[[float], Awaitable[None]],
    *,
    stop: asyncio.Event,
    duration_s: float | None = None,
    timing: TickTiming | None = None,
) -> TickTiming:
    """Call ``tick(deadline)`` at ``deadline = t0 + k * period_s`` until ``stop`` is set.

    With ``duration_s``, the last tick is the last deadline within
    ``t0 + duration_s`` (so ``duration_s / period_s + 1`` ticks when nothing
    overruns). Returns the counters (also updated live in ``timing``).
    """
    timing = timing or TickTiming()
    deadline = clock.now()
    until_s = None if duration_s is None else deadline + duration_s
    while not stop.is_set() and (until_s is None or deadline <= until_s + 1e-9):
        await clock.sleep_until(deadline)
        if stop.is_set():
            break
        lateness_s = clock.now() - deadline
        timing.last_lateness_s = lateness_s
        timing.max_lateness_s = max(timing.max_lateness_s, lateness_s)
        await tick(deadline)
        timing.ticks += 1
        deadline += period_s
        behind_s = clock.now() - deadline
        if behind_s > 0:
            missed = math.floor(behind_s / period_s) + 1
            timing.overruns += missed
            deadline += missed * period_s
            log.warning("overrun", missed_deadlines=missed, behind_s=round(behind_s, 4))
    return timing
