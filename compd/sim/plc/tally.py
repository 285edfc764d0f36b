"""What a simulated run's inputs went through, tick by tick: the episodes and the time behind the summary.

The daemon's ``signal_faults`` counter counts an input going *faulted* (its
own checks failed for longer than ``hold_s``); an input held through a short
link outage, or replaced by its prediction from the other sensors for an hour
(a stand-in, :mod:`compd.service.loop.plausibility`), never is. The end of a
simulated run answers "what happened to my signals" from every tick's health
instead: an episode begins when an input leaves ``ok`` (held, faulted or
estimated) and ends when it is ``ok`` again, and the time on a stand-in is
summed per input. Drift flags (the CUSUM's, a slow departure) are counted
from the plausibility check, across a model switch that builds a new one.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from compd.service.loop.compensator import TickRecord
from compd.service.loop.plausibility import Plausibility
from compd.service.loop.signals import Health


@dataclass
class InputTally:
    """One input over a run: its episodes away from ``ok`` and the seconds in each state."""

    #: Episodes: the input left ``ok`` (held, faulted or estimated) and came back or the run ended.
    episodes: int = 0
    #: Of those, the ones in which it was faulted at some tick, and those a stand-in bridged.
    faulted_episodes: int = 0
    stand_in_episodes: int = 0
    held_s: float = 0.0
    faulted_s: float = 0.0
    #: Seconds the model ran on the input's prediction from the other sensors (a stand-in).
    stand_in_s: float = 0.0
    _health: Health = Health.OK
    _faulted_now: bool = False
    _stand_in_now: bool = False

    def observe(self, health: Health, period_s: float) -> None:
        if health is not Health.OK and self._health is Health.OK:
            self.episodes += 1
            self._faulted_now = self._stand_in_now = False
        if health is Health.HELD:
            self.held_s += period_s
        elif health is Health.FAULTED:
            self.faulted_s += period_s
            if not self._faulted_now:
                self._faulted_now = True
                self.faulted_episodes += 1
        elif health is Health.ESTIMATED:
            self.stand_in_s += period_s
            if not self._stand_in_now:
                self._stand_in_now = True
                self.stand_in_episodes += 1
        self._health = health


@dataclass
class SignalTally:
    """Every input's :class:`InputTally` over a run, and the drift flags raised."""

    period_s: float
    inputs: dict[str, InputTally] = field(default_factory=dict)
    #: Drift flags of the plausibility checks that ran before the current one (a model switch).
    _drifts_before: int = 0
    _plausibility: Plausibility | None = None

    def observe(self, record: TickRecord, plausibility: Plausibility | None = None) -> None:
        """Take one tick's health of every input, and the plausibility check that judged it."""
        for name, health in record.health.items():
            self.inputs.setdefault(name, InputTally()).observe(health, self.period_s)
        if plausibility is not self._plausibility:
            if self._plausibility is not None:
                self._drifts_before += self._plausibility.drifts
            self._plausibility = plausibility

    @property
    def episodes(self) -> int:
        """Signal fault episodes of all inputs: each input away from ``ok`` once is one."""
        return sum(t.episodes for t in self.inputs.values())

    @property
    def drift_flags(self) -> int:
        """Inputs flagged as drifting from the other sensors (each a stand-in episode too)."""
        now = 0 if self._plausibility is None else self._plausibility.drifts
        return self._drifts_before + now
