"""Each model input against the others, and the virtual sensor that stands in for a wrong one.

A sensor can be wrong inside every limit of its own: a Pt100 reading 45 degC
where the spindle is at 30 passes the range check, and once the hold is over
any rate check has nothing left to compare with; one that drifts 1 degC an
hour passes every check that compares it with its own recent past. The other
sensors know better. With a consistency model in the model file
(:mod:`compd.model.consistency`), every tick:

1. each checked input whose own checks passed (:mod:`compd.service.loop.signals`) is
   compared with its prediction from the other signals: its residue (reading
   minus prediction) may move from its level of the last minutes by at most
   the tolerance ``max(k_sigma * sigma, min_tolerance)`` (its unit); the one
   furthest out is judged wrong and left out of the others' predictions, and
   so on until all that remain agree: one wrong sensor does not drag its
   neighbours along;
2. a slow departure is caught by a CUSUM (:mod:`compd.model.drift`) of each
   residue against its level over the last hour, in the calibration's own
   sigma, not by that wide tolerance (from an hour after the check starts:
   its low-passes start at rest, and the hour's level must form first); the input to blame is the one whose
   removal from the predictions brings the others back (a drifting spindle
   moves the headstock's prediction too), never an input a redundant partner
   vouches for;
3. an input judged wrong, or failing its own checks, is **replaced by its
   prediction** (health ``ESTIMATED``: a status bit and level degraded; the
   axis keeps compensating), shifted by the residue it had before the
   episode (for a drift: before the departure began);
4. it is used again only **on evidence**: its residue back within
   ``release_k_sigma`` sigmas (grown with the episode's length as the
   prediction's own error wanders: its square root under an hour, linearly
   beyond; never below ``release_floor``) of its
   level before the episode for ``confirm_ticks`` ticks in a row, or a person
   saying so (``compd sensor trust NAME``, :meth:`Plausibility.trust`). A
   reading merely back inside the wide tolerance is not evidence.

A level is kept as the signals' averaged features, not as an averaged
residue: the residue is linear in the features, so the level of any input
under any set of predictors is exact, and an input's level survives another
sensor failing (two sensors at once; :meth:`ConsistencyCheck.residues`).

Each episode is one ERROR line at its start (the sensor, what it read, the
prediction and the tolerance) and one at its end, an event and a count.
When the remaining signals explain too little of an input (too few healthy
sensors, or all of them outside what the calibration saw), there is no
prediction and the input is held and faulted as without a consistency model;
a reading that passes its own checks again is used only if it did not jump
from the value in use meanwhile (``max_jump``, else ``min_tolerance``): a
reading that came back elsewhere needs the other sensors or a person.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping
from dataclasses import dataclass

import numpy as np
import structlog

from compd.errors import CompdError
from compd.faultlog import EventSink, FaultLog
from compd.model.consistency import ConsistencyCheck, Prediction
from compd.model.drift import CusumSettings, DriftCusum
from compd.service.loop.signals import Health, Reading, SignalMonitor

log = structlog.get_logger("compd.service.loop.plausibility")

#: A good input's level is the signals' features averaged over about this long (s): a reading is
#: judged by how far its residue jumped from that level. The prediction's own error drifts
#: slowly (a programme the calibration did not run), a failing sensor jumps or freezes.
ANCHOR_TAU_S = 300.0
#: The drift reference: the features averaged over about an hour (s), the horizon the
#: calibration's sigma measures the residue's change over (:data:`compd.model.consistency.DRIFT_HORIZON_S`).
REFERENCE_TAU_S = 3600.0
#: A released input's residue must be back near its level before the episode: within
#: ``release_k_sigma`` sigmas of the change over the episode's length, at least this long (s).
RELEASE_MIN_S = 600.0


@dataclass(frozen=True)
class PlausibilitySettings:
    """How far from its prediction a reading may be, how fast it may depart, how it is trusted again."""

    k_sigma: float = 8.0
    #: The smallest tolerance, in the signal's unit: a prediction is never trusted closer than this.
    min_tolerance: float = 3.0
    confirm_ticks: int = 30
    #: The drift CUSUM's allowance (sigmas) and alarm threshold (sigma-hours), :mod:`compd.model.drift`.
    drift_k_sigma: float = 3.0
    drift_h_sigma_h: float = 0.25
    #: A stand-in ends once the residue is back within this many sigmas of its level before...
    release_k_sigma: float = 3.0
    #: ...and never closer than this (the signal's unit: a Pt100's noise and quantisation).
    release_floor: float = 0.1


#: The settings a config without a ``plausibility`` section gets.
DEFAULT_SETTINGS = PlausibilitySettings()


@dataclass
class _Episode:
    started_s: float
    reason: str
    #: The averaged features before the episode: the input's level then, under any predictors.
    before: np.ndarray
    agreeing: int = 0
    #: A person said the sensor is right (``compd sensor trust``): used at its next good reading.
    trusted: bool = False


class Plausibility:
    """Judges the checked inputs each tick; :meth:`judge` returns the readings the model should use."""

    def __init__(
        self,
        check: ConsistencyCheck,
        monitors: Mapping[str, SignalMonitor],
        units: Mapping[str, str],
        period_s: float,
        settings: PlausibilitySettings = DEFAULT_SETTINGS,
    ) -> None:
        self.check = check
        self.monitors = monitors
        self.units = dict(units)
        self.settings = settings
        self.checked = [name for name in check.model.checked if name in monitors]
        self._short_a = math.exp(-period_s / ANCHOR_TAU_S)
        self._reference_a = math.exp(-period_s / REFERENCE_TAU_S)
        #: The features averaged over :data:`ANCHOR_TAU_S` and :data:`REFERENCE_TAU_S`.
        self._short: np.ndarray | None = None
        self._reference: np.ndarray | None = None
        model = check.model
        self._cusum = DriftCusum(
            len(model.checked),
            period_s,
            CusumSettings(settings.drift_k_sigma, settings.drift_h_sigma_h),
        )
        #: When the check began (s): its low-passes start at rest, its hour's reference forms
        #: over the first :data:`REFERENCE_TAU_S`; no drift is judged before.
        self._started_s: float | None = None
        #: Per input, the reference when its CUSUM last left zero (where a departure began).
        self._departed: dict[str, np.ndarray] = {}
        self._groups = model.groups()
        #: Per checked input, the value the model used last tick.
        self._used: dict[str, float] = {}
        self.episodes: dict[str, _Episode] = {}
        self.predictions: dict[str, Prediction | None] = {}
        self.faults = {name: FaultLog(log, signal=name, end_level="error") for name in self.checked}
        #: Episodes begun since start (a virtual sensor stood in), and how many of them were drifts.
        self.count = 0
        self.drifts = 0

    def report_to(self, sink: EventSink) -> None:
        for fault in self.faults.values():
            fault.sink = sink

    def tolerance(self, prediction: Prediction) -> float:
        return max(self.settings.k_sigma * prediction.sigma, self.settings.min_tolerance)

    def release_tolerance(self, prediction: Prediction, lasted_s: float) -> float:
        """How near its level before the episode a returning input's residue must be (its unit)."""
        hours = max(lasted_s, RELEASE_MIN_S) / 3600.0
        # The prediction's own error wanders like a random walk over minutes and persists as a
        # bias over hours (a programme the calibration did not run): sqrt, then linear.
        spread = self.settings.release_k_sigma * prediction.sigma * max(math.sqrt(hours), hours)
        return max(spread, self.settings.release_floor)

    def trust(self, name: str) -> str:
        """A person vouches for ``name``'s sensor: its next good reading ends its stand-in."""
        if name not in self.checked:
            known = ", ".join(self.checked) or "none"
            raise CompdError(f"{name!r} is not checked against the others; checked inputs: {known}")
        episode = self.episodes.get(name)
        if episode is None:
            return f"{name} is not stood in for: its readings are used already"
        episode.trusted = True
        log.warning("signal trusted by a person: its next good reading is used", signal=name)
        return f"{name}: its next reading that passes its own checks is used again"

    def judge(
        self,
        t_s: float,
        readings: dict[str, Reading],
        read: Mapping[str, float | None],
        verified: Collection[str] = (),
    ) -> dict[str, Reading]:
        """The readings to use this tick, wrong inputs replaced by their predictions.

        ``read``: what each read; ``verified``: inputs a redundant partner vouches
        for this tick, never blamed for a jump or for the others' departures.
        """
        check = self.check
        values = {name: r.value for name, r in readings.items()}
        z = check.features(values)
        if self._short is None:
            self._short, self._reference = z.copy(), z.copy()
        suspect = {n for n in self.checked if n in self.episodes}
        bad = {n for n, r in readings.items() if r.health is not Health.OK} | suspect
        ok = check.usable(z, bad)
        candidates = [n for n in self.checked if n not in bad]
        predictions = self._predictions(z, ok)
        while candidates:
            levels = self._levels(self._short, ok)
            scores = {
                name: abs(values[name] - p.value - levels[name]) / self.tolerance(p)
                for name in candidates
                if (p := predictions[name]) is not None and name not in verified
            }
            worst = max(scores, key=scores.__getitem__, default=None)
            if worst is None or scores[worst] <= 1.0:
                break
            self._begin(
                t_s,
                worst,
                read.get(worst),
                predictions,
                ok,
                self._short,
                "disagrees with the other sensors",
            )
            candidates.remove(worst)
            ok[check.model.signals.index(worst)] = False
            predictions = self._predictions(z, ok)
        if self._started_s is None:
            self._started_s = t_s
        settled = t_s - self._started_s >= REFERENCE_TAU_S
        drifting = self._drift(z, ok, candidates, predictions, verified) if settled else None
        if drifting is not None:
            name, before, why = drifting
            self._begin(t_s, name, read.get(name), predictions, ok, before, why)
            self.drifts += 1
            candidates.remove(name)
            ok[check.model.signals.index(name)] = False
            predictions = self._predictions(z, ok)
        vouched = {n for n, e in self.episodes.items() if e.trusted}
        out = dict(readings)
        for name in self.checked:
            if name not in candidates:
                out[name] = self._stand_in(
                    t_s, name, readings[name], read.get(name), predictions, ok
                )
        self.predictions = predictions
        if any(out[n] is not readings[n] or n in vouched for n in self.checked):
            # The low-passes take what was used (from a vouched sensor's shifted state).
            z = check.features({n: r.value for n, r in out.items()})
        check.advance(z)
        self._average(z)
        for name in self.checked:
            if math.isfinite(out[name].value):
                self._used[name] = out[name].value
        return out

    def _stand_in(
        self,
        t_s: float,
        name: str,
        reading: Reading,
        now: float | None,
        predictions: dict[str, Prediction | None],
        ok: np.ndarray,
    ) -> Reading:
        """The reading to use for ``name``, not a candidate this tick (its own checks failed, or stood in)."""
        p = predictions[name]
        if name not in self.episodes and reading.health is not Health.OK and p is not None:
            self._begin(t_s, name, now, predictions, ok, self._short, reading.reason)
        episode = self.episodes.get(name)
        if episode is None:
            return reading
        monitor = self.monitors[name]
        reference = now if now is not None and math.isfinite(now) else math.nan
        if episode.trusted and reading.health is Health.OK:
            self._end(t_s, name, reading.value, p, "a person trusts it: its readings are used")
            self._vouched(name, reading.value)
            return reading
        if p is None:
            # Nothing left to predict it from: as without a consistency model, but a reading that
            # passes its own checks is used only if it is where the model's value was (nothing
            # can confirm or refute it; one that came back elsewhere needs a person).
            held = self._used.get(name, monitor.last_good)
            jumped = reading.value - held
            if reading.health is Health.OK and abs(jumped) <= self._steady_tolerance(name):
                self._end(
                    t_s, name, reading.value, None,
                    "signal passes its own checks again (no other sensors to judge it): its readings are used",
                )  # fmt: skip
                return reading
            why = f"no prediction: {episode.reason}"
            if reading.health is Health.OK:
                why = (
                    f"no other sensors to judge it, and it reads {jumped:+.2f} {self.units.get(name, '')} "
                    f"from the value in use: 'compd sensor trust {name}' once it is checked"
                )
            out = Reading(held, Health.FAULTED, why)
            monitor.rebase(out, reference if math.isfinite(reference) else held)
            return out
        before = self._level(episode.before, ok, name)
        lasted_s = t_s - episode.started_s
        agrees = reading.health is Health.OK and abs(
            reading.value - p.value - before
        ) <= self.release_tolerance(p, lasted_s)
        episode.agreeing = episode.agreeing + 1 if agrees else 0
        if episode.agreeing >= self.settings.confirm_ticks:
            self._end(
                t_s,
                name,
                reading.value,
                p,
                "signal agrees with the other sensors again: its readings are used",
            )
            return reading
        out = Reading(
            p.value + before,
            Health.ESTIMATED,
            f"estimated from the other sensors: {episode.reason}",
        )
        monitor.rebase(out, reference if math.isfinite(reference) else out.value)
        return out

    def _steady_tolerance(self, name: str) -> float:
        jump = self.monitors[name].checks.max_jump
        return jump if jump is not None else self.settings.min_tolerance

    def _predictions(self, z: np.ndarray, ok: np.ndarray) -> dict[str, Prediction | None]:
        """Every checked input's prediction from the signals ``ok`` marks (None: too little to go on)."""
        values, sigmas = self.check.predict_all(z, ok)
        out: dict[str, Prediction | None] = {}
        for name, value, sigma in zip(self.check.model.checked, values, sigmas, strict=True):
            if not math.isfinite(sigma):
                out[name] = None
                continue
            out[name] = Prediction(float(value), float(sigma))
        return out

    def _levels(self, averaged: np.ndarray | None, ok: np.ndarray) -> dict[str, float]:
        """Every checked input's residue of the averaged features ``averaged`` under the predictors
        ``ok`` marks (0 where there is none): its level, against which a jump is judged."""
        if averaged is None:
            return dict.fromkeys(self.check.model.checked, 0.0)
        residues, _ = self.check.residues(averaged, ok)
        return {
            name: float(r) if math.isfinite(r) else 0.0
            for name, r in zip(self.check.model.checked, residues, strict=True)
        }

    def _level(self, averaged: np.ndarray | None, ok: np.ndarray, name: str) -> float:
        """``name``'s level under the predictors ``ok`` marks (:meth:`_levels`)."""
        return self._levels(averaged, ok)[name]

    def _drift(
        self,
        z: np.ndarray,
        ok: np.ndarray,
        candidates: list[str],
        predictions: dict[str, Prediction | None],
        verified: Collection[str],
    ) -> tuple[str, np.ndarray, str] | None:
        """The input to blame for a slow departure this tick, the features before it began, and why."""
        reference = self._reference
        if reference is None:
            return None
        g = self._departures(z, ok, candidates)
        departed, alarmed = self._cusum.step(g)
        names = self.check.model.checked
        for i in np.flatnonzero(departed):
            self._departed[names[i]] = reference.copy()
        for i in np.flatnonzero(self._cusum.statistic == 0.0):
            self._departed.pop(names[i], None)
        if not alarmed.any():
            return None
        eligible = [c for c in candidates if c not in verified and predictions[c] is not None]
        culprit = self._isolate(z, ok, eligible, candidates)
        first = names[int(np.argmax(np.where(alarmed, self._cusum.statistic, -1.0)))]
        self._cusum.reset()
        departures = self._departed
        self._departed = {}
        if culprit is None:
            return None
        before = departures.get(culprit, departures.get(first, reference))
        row = names.index(culprit)
        p = predictions[culprit]
        assert p is not None
        moved = float(g[row] * p.sigma) if math.isfinite(g[row]) else math.nan
        unit = self.units.get(culprit, "")
        why = (
            f"drifts from the other sensors: its residue moved {moved:+.2f} {unit} from its level "
            f"over the last hour (sigma {p.sigma:.3g} {unit} an hour)"
        )
        return culprit, before, why

    def _departures(self, z: np.ndarray, ok: np.ndarray, judged: Collection[str]) -> np.ndarray:
        """Per checked input in ``judged``: its residue's departure from the hour's level, in sigmas."""
        now, sigmas = self.check.residues(z, ok)
        assert self._reference is not None
        then, _ = self.check.residues(self._reference, ok)
        mask = np.array([n in judged for n in self.check.model.checked])
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(mask, (now - then) / sigmas, math.nan)

    def _isolate(
        self, z: np.ndarray, ok: np.ndarray, eligible: list[str], judged: list[str]
    ) -> str | None:
        """Of ``eligible``, the input whose removal from the predictions best brings the others back."""
        best, best_score = None, math.inf
        for name in eligible:
            without = ok.copy()
            without[self.check.model.signals.index(name)] = False
            others = [n for n in judged if n != name]
            g = np.abs(self._departures(z, without, others))
            score = float(np.nanmax(g)) if np.isfinite(g).any() else 1e9
            if score < best_score:
                best, best_score = name, score
        return best

    def _average(self, z: np.ndarray) -> None:
        """Advance the short and hour-long averages of the features with this tick's."""
        for averaged, a in ((self._short, self._short_a), (self._reference, self._reference_a)):
            assert averaged is not None
            finite = np.isfinite(z)
            fresh = finite & ~np.isfinite(averaged)
            averaged[finite] = a * averaged[finite] + (1 - a) * z[finite]
            averaged[fresh] = z[fresh]

    def _vouched(self, name: str, value: float) -> None:
        """A person vouched for ``name`` reading ``value``: the gap to its stand-in is its offset
        from now on, in its low-passes and its levels, so nothing departs because of it."""
        delta = value - self._used.get(name, value)
        if not math.isfinite(delta):
            return
        self.check.shift(name, delta)
        start = self._groups[self.check.model.signals.index(name)][0]
        for averaged in (self._short, self._reference):
            if averaged is not None:
                averaged[start : start + 1 + len(self.check.model.taus_s)] += delta
        self._cusum.reset()
        self._departed.clear()

    def _begin(
        self,
        t_s: float,
        name: str,
        value: float | None,
        predictions: dict[str, Prediction | None],
        ok: np.ndarray,
        before: np.ndarray | None,
        reason: str,
    ) -> None:
        p = predictions[name]
        assert p is not None
        snapshot = (before if before is not None else self.check.features({})).copy()
        level = self._level(snapshot, ok, name)
        self.episodes[name] = _Episode(t_s, reason, snapshot)
        self.count += 1
        unit = self.units.get(name, "")
        self.faults[name].failed(
            "signal replaced by its prediction from the other sensors",
            read=_round(value),
            predicted=_round(p.value + level),
            tolerance=_round(self.tolerance(p)),
            unit=unit,
            reason=reason,
            predicted_from=[
                s
                for s, good in zip(self.check.model.signals, ok, strict=True)
                if good and s != name
            ],
        )

    def _end(self, t_s: float, name: str, value: float, p: Prediction | None, why: str) -> None:
        episode = self.episodes.pop(name)
        self.faults[name].cleared(
            why,
            read=_round(value),
            predicted=None if p is None else _round(p.value),
            unit=self.units.get(name, ""),
            lasted_s=round(t_s - episode.started_s, 1),
        )


def _round(value: float | None) -> float | str | None:
    """A figure for the log: rounded, or what it was (``nan``, ``inf``; None: nothing was read)."""
    if value is None:
        return None
    return round(value, 3) if math.isfinite(value) else str(value)
