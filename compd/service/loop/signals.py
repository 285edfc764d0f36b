"""Per-signal plausibility checks and the hold logic: what the model is fed when a sensor misbehaves.

Each tick a signal's reading (already scaled to its unit, or ``None`` when
the driver gave no new value) passes the checks its config names:

- **range**: ``min <= value <= max`` (and finite);
- **spike**: ``|value - last_good| <= max_jump``, in the signal's unit per tick;
- **stuck** (optional): the value stays within ``stuck_tolerance`` of itself
  for ``stuck_s`` seconds, which a live thermal sensor's noise never does;
- **stale**: no new value for ``stale_s`` seconds (a missing reading younger
  than that is bridged silently with the last one: a bus hiccup is not a fault).

A bad reading is replaced by the last good value (``HELD``) for at most
``hold_s`` seconds from the first bad reading; after that the signal is
``FAULTED`` and the axes that depend on it freeze (see :mod:`compd.service.loop.safety`).
A good reading ends a hold or a fault at once. After a fault the spike check
is suspended for the first reading: the true value may have moved further
than ``max_jump`` meanwhile, and it must be possible to recover. With a
consistency model (:mod:`compd.service.loop.plausibility`) that reading is not
trusted on its own: it must agree with the other sensors for a while first.

Pure: the caller passes the time, nothing here reads a clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum


class Health(IntEnum):
    """A signal's state at one tick.

    ``ESTIMATED`` (a wrong reading replaced by its prediction from the other
    sensors, :mod:`compd.service.loop.plausibility`) is numbered after the others so
    that recorded codes keep their meaning; it ranks between held and faulted.
    """

    OK = 0
    HELD = 1
    FAULTED = 2
    ESTIMATED = 3


@dataclass(frozen=True)
class Checks:
    """The checks of one signal; ``None`` switches a check off."""

    min: float | None = None
    max: float | None = None
    stale_s: float = 10.0
    stuck_s: float | None = None
    stuck_tolerance: float = 0.0
    max_jump: float | None = None
    hold_s: float = 30.0


@dataclass(frozen=True, slots=True)
class Reading:
    """The value to use this tick (``nan`` only before the first good value) and why."""

    value: float
    health: Health
    reason: str = ""


class SignalMonitor:
    """Checks one signal tick by tick; :meth:`update` returns the value the model should use."""

    def __init__(self, name: str, checks: Checks) -> None:
        self.name = name
        self.checks = checks
        self.last_good = math.nan
        self.last_good_t: float | None = None
        self.last_received_t: float | None = None
        self.bad_since: float | None = None
        self.reading = Reading(math.nan, Health.FAULTED, "no value yet")
        self._stuck_value = math.nan
        self._stuck_since: float | None = None

    def update(self, now_s: float, value: float | None) -> Reading:
        """Take this tick's reading (``None``: no new value) at time ``now_s`` (s)."""
        problem = self._problem(now_s, value)
        if problem is None:
            assert value is not None
            self.last_good, self.last_good_t, self.bad_since = value, now_s, None
            self.reading = Reading(value, Health.OK)
        elif problem == "":
            # A missing reading within stale_s: bridged with the last good value.
            self.reading = Reading(self.last_good, self.reading.health, self.reading.reason)
        else:
            if self.bad_since is None:
                self.bad_since = now_s
            held = self.last_good_t is not None and now_s - self.bad_since < self.checks.hold_s
            self.reading = Reading(self.last_good, Health.HELD if held else Health.FAULTED, problem)
        return self.reading

    def rebase(self, reading: Reading, reference: float) -> None:
        """Use ``reading`` (a stand-in for a wrong value) this tick; the next reading's rate is
        checked against ``reference``.

        While a stand-in is used, the reference is the sensor's own last
        reading (where it read a finite value): a sensor back from a fault
        reads steadily again, and whether that value is right is for the
        other sensors to say, not for a stand-in that may be a few degrees off.
        """
        self.last_good = reference
        self.reading = reading

    def _problem(self, now_s: float, value: float | None) -> str | None:
        """``None`` if good, ``""`` if missing but not yet stale, else the reason it is bad."""
        checks = self.checks
        if value is None:
            if self.last_received_t is None:
                return "no value yet"
            if now_s - self.last_received_t >= checks.stale_s:
                return f"stale: no new value for {now_s - self.last_received_t:.0f} s"
            return "" if self.reading.health is Health.OK else self.reading.reason
        self.last_received_t = now_s
        if not math.isfinite(value):
            return f"not finite ({value})"
        if checks.min is not None and value < checks.min:
            return f"{value:g} below min {checks.min:g}"
        if checks.max is not None and value > checks.max:
            return f"{value:g} above max {checks.max:g}"
        recovering = self.reading.health is Health.FAULTED
        if (
            checks.max_jump is not None
            and not recovering
            and self.last_good_t is not None
            and abs(value - self.last_good) > checks.max_jump
        ):
            return f"spike: jump of {value - self.last_good:+g} exceeds {checks.max_jump:g}"
        if checks.stuck_s is not None:
            if self._stuck_since is None or abs(value - self._stuck_value) > checks.stuck_tolerance:
                self._stuck_value, self._stuck_since = value, now_s
            elif now_s - self._stuck_since >= checks.stuck_s:
                return f"stuck at {self._stuck_value:g} for {now_s - self._stuck_since:.0f} s"
        return None
