"""Gain scheduling: the model's named gains chosen by an operating condition, ramped bumplessly.

Post-process 2024 eq. 6 weighs whole sub-models by gains ``g1, g2, ...`` that
``compd update`` optimises for one technological condition (a spindle head,
a range of axis positions, a part program). A gain table keyed by a
configured signal lets the daemon use each condition's gains::

    gain_schedule:
      signal: spindle_head          # any signal under 'signals'
      table:
        - {when: 1, gains: {g1: 1.0, g2: 0.8}}              # exact whole number
        - {when: {min: 0, max: 250}, gains: {g1: 1.1}}      # min <= value < max
      default: {g1: 1.0, g2: 1.0}   # optional: when no row matches
      ramp_s: 30

Rules, in order:

- a row's gains overlay the model file's own: a gain a row does not name
  keeps the value the model file gives it;
- no row matches: ``default`` when given, else the model file's own gains;
- the key signal is faulted (or has never had a good value): the row last
  chosen is held (a ramp under way finishes); before any good value that is
  ``default`` (else the model file's gains);
- a change of row ramps every gain linearly from its value at that moment to
  the new row's over ``ramp_s`` (s)::

      g(t) = g_from + min(1, (t - t_change) / ramp_s) * (g_to - g_from)

  so the offset moves by at most ``|dg . c| / ramp_s`` per second beyond the
  thermal drift itself (``c`` the sub-models' contributions): it never steps.
  The safety stage's slew limit stays a second line of defence. The row
  chosen at the very first tick, when nothing has been written yet, applies
  at once.

Ranges have no hysteresis: a key dithering on a bound turns the ramp back and
forth, which keeps the gains continuous but never lets them settle; put
bounds where the machine does not dwell.

Pure: the caller passes the time and the key signal's reading; the gains go
to a :class:`~compd.model.run.TickRunner` through :meth:`GainScheduler.apply`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # annotations only: a config is read without loading the model stack
    from compd.model.compiled import CompiledModel
    from compd.model.run import TickRunner


#: A reading within this of a row's whole number matches it (a scaled ``float`` signal).
WHOLE_TOLERANCE = 1e-6


@dataclass(frozen=True)
class GainRow:
    """One row of the table: ``gains`` (name -> value) while the key matches.

    ``value`` set: the key equals that whole number (a head id, a program
    number); else the half-open range ``low <= key < high`` (an axis
    position), so that adjacent ranges share a bound without overlapping.
    """

    gains: Mapping[str, float]
    value: int | None = None
    low: float = -math.inf
    high: float = math.inf

    def matches(self, key: float) -> bool:
        if self.value is not None:
            return abs(key - self.value) <= WHOLE_TOLERANCE
        return self.low <= key < self.high

    def overlaps(self, other: GainRow) -> bool:
        """True when some key value would match both rows."""
        if self.value is not None and other.value is not None:
            return self.value == other.value
        if self.value is not None:
            return other.matches(self.value)
        if other.value is not None:
            return self.matches(other.value)
        return self.low < other.high and other.low < self.high

    def describe(self) -> str:
        if self.value is not None:
            return f"= {self.value}"
        return f"in [{self.low:g}, {self.high:g})"


@dataclass(frozen=True)
class GainTable:
    """The configured schedule: key signal, rows, fallback and ramp time (s)."""

    signal: str
    rows: tuple[GainRow, ...]
    default: Mapping[str, float] | None = None
    ramp_s: float = 30.0

    def lookup(self, key: float) -> int | None:
        """The index of the row ``key`` matches, or None (the rows never overlap)."""
        for i, row in enumerate(self.rows):
            if row.matches(key):
                return i
        return None

    @property
    def names(self) -> tuple[str, ...]:
        """Every gain name the table or the default sets, in first-use order."""
        seen: dict[str, None] = {}
        for gains in [row.gains for row in self.rows] + [self.default or {}]:
            seen |= dict.fromkeys(gains)
        return tuple(seen)


def first_overlap(rows: Sequence[GainRow]) -> tuple[int, int] | None:
    """The first pair ``(i, j)``, ``i < j``, of rows some key would match both, or None."""
    for j, row in enumerate(rows):
        for i in range(j):
            if rows[i].overlaps(row):
                return i, j
    return None


def model_gains(compiled: CompiledModel) -> dict[str, float]:
    """The model file's own named gains (the first sub-model's value where a name is shared)."""
    gains: dict[str, float] = {}
    for sub in compiled.submodels:
        if sub.gain_name is not None:
            gains.setdefault(sub.gain_name, float(sub.gain))
    return gains


#: The row in force when no row matches (``default``, else the model file's gains).
NO_ROW = -1


class GainScheduler:
    """The schedule's state from tick to tick: the row in force and the ramp towards it.

    Each tick, :meth:`update` with the key signal's value (``usable=False``
    when it is faulted), then :meth:`apply` to each runner before it steps.
    """

    def __init__(self, table: GainTable) -> None:
        self.table = table
        #: Index of the row in force, :data:`NO_ROW`, or None before the first good key value.
        self.row: int | None = None
        #: The key signal is faulted: the row in force is held.
        self.held = False
        #: The gains last given to a runner (name -> value), for the status and the recorder.
        self.applied: dict[str, float] = {}
        self._to = dict(table.default or {})
        self._from = dict(self._to)
        self._start_s = -math.inf
        self._weight = 1.0
        self._ticks = 0
        self._base_of: tuple[CompiledModel | None, dict[str, float]] = (None, {})

    @property
    def ramping(self) -> bool:
        return self._weight < 1.0

    def update(self, t_s: float, key: float, *, usable: bool = True) -> None:
        """Choose the row for ``key`` at ``t_s`` (s) and advance the ramp."""
        first = self._ticks == 0
        self._ticks += 1
        self.held = not (usable and math.isfinite(key))
        if not self.held:
            found = self.table.lookup(key)
            row = NO_ROW if found is None else found
            if row != self.row:
                # Ramp from where the gains are now, mid-ramp values included; a name
                # no runner has had yet starts from each model's own value.
                self._from = self._resolve(self._base_of[1])
                self._to = dict(
                    (self.table.default or {}) if found is None else self.table.rows[found].gains
                )
                # Nothing was written before the first tick: no ramp needed.
                self._start_s = -math.inf if first else t_s
                self.row = row
        ramp_s = self.table.ramp_s
        self._weight = 1.0 if ramp_s <= 0 else min(1.0, max(0.0, (t_s - self._start_s) / ramp_s))

    def apply(self, runner: TickRunner) -> None:
        """Give ``runner`` the scheduled gains (a no-op when it already has them)."""
        gains = self._resolve(self._base(runner.compiled))
        if any(runner.gains.get(name, value) != value for name, value in gains.items()):
            runner.set_gains({name: v for name, v in gains.items() if name in runner.gains})
        self.applied = gains

    def status(self) -> dict[str, Any]:
        """JSON-able: the key signal, the row in force, the gains in use, ramping or held."""
        fallback = "default" if self.table.default else "model file gains"
        if self.row is None:
            when = f"no good value yet: {fallback}"
        elif self.row == NO_ROW:
            when = f"no row matches: {fallback}"
        else:
            when = f"{self.table.signal} {self.table.rows[self.row].describe()}"
        return {
            "signal": self.table.signal,
            "row": None if self.row is None or self.row == NO_ROW else self.row,
            "when": when,
            "gains": dict(self.applied),
            "ramping": self.ramping,
            "held": self.held,
        }

    def _base(self, compiled: CompiledModel) -> dict[str, float]:
        if self._base_of[0] is not compiled:
            self._base_of = (compiled, model_gains(compiled))
        return self._base_of[1]

    def _resolve(self, base: Mapping[str, float]) -> dict[str, float]:
        """Each scheduled gain now, ``base`` standing in for names an end leaves unset.

        A name neither an end nor ``base`` sets is left out (each runner's own
        value then stands in for it).
        """
        w = self._weight
        gains = {}
        for name in self.table.names:
            start = self._from.get(name, base.get(name))
            end = self._to.get(name, base.get(name))
            if start is not None and end is not None:
                gains[name] = start + w * (end - start)
        return gains
