"""Each model input against the others, and the virtual sensor that stands in for a wrong one.

A sensor can be wrong inside every limit of its own: a Pt100 reading 45 degC
where the spindle is at 30 passes the range check, and once the hold is over
any rate check has nothing left to compare with. The other sensors know
better. With a consistency model in the model file
(:mod:`compd.model.consistency`), every tick:

1. each checked input whose own checks passed (:mod:`compd.service.loop.signals`) is
   compared with its prediction from the other signals: its residue (reading
   minus prediction) may move from its level of the last minutes by at most
   the tolerance ``max(k_sigma * sigma, min_tolerance)`` (its unit); the one
   furthest out is judged wrong and left out of the others' predictions, and
   so on until all that remain agree: one wrong sensor does not drag its
   neighbours along. The tolerance is wide on purpose: a stand-in costs
   compensation accuracy (the model's gains on collinear temperatures are
   large), so only a reading far off is replaced on the others' word alone;
   steps, freezes and wire breaks are caught by the signal's own checks;
2. an input judged wrong, or failing its own checks, is **replaced by its
   prediction** (health ``ESTIMATED``: a status bit and level degraded; the
   axis keeps compensating), shifted by the residue it had before the
   episode (the prediction's own error is slow, so this keeps the model's
   output continuous);
3. it is used again only after its readings passed its own checks and agreed
   with the prediction for ``confirm_ticks`` ticks in a row: a reading that
   merely stopped jumping is not yet a good one.

Each episode is one ERROR line at its start (the sensor, what it read, the
prediction and the tolerance) and one at its end, an event and a count.
When the remaining signals explain too little of an input (too few healthy
sensors, or all of them outside what the calibration saw), there is no
prediction and the input is held and faulted as without a consistency model.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import structlog

from compd.faultlog import EventSink, FaultLog
from compd.model.consistency import ConsistencyCheck, Prediction
from compd.service.loop.signals import Health, Reading, SignalMonitor

log = structlog.get_logger("compd.service.loop.plausibility")

#: A good input's residue (reading minus prediction) is followed over about this long (s): a
#: reading is judged by how far its residue jumped from that level, and a stand-in is the
#: prediction shifted by it. The prediction's own error drifts slowly (a programme the
#: calibration did not run), a failing sensor jumps or freezes.
ANCHOR_TAU_S = 300.0


@dataclass(frozen=True)
class PlausibilitySettings:
    """How far from its prediction a reading may be, and how long it must agree to be trusted again."""

    k_sigma: float = 8.0
    #: The smallest tolerance, in the signal's unit: a prediction is never trusted closer than this.
    min_tolerance: float = 3.0
    confirm_ticks: int = 30


#: The settings a config without a ``plausibility`` section gets.
DEFAULT_SETTINGS = PlausibilitySettings()


@dataclass
class _Episode:
    started_s: float
    reason: str
    agreeing: int = 0


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
        self._anchor_a = math.exp(-period_s / ANCHOR_TAU_S)
        #: Per checked input, its recent residue (reading minus prediction) while it was good.
        self.residue: dict[str, float] = {}
        self.episodes: dict[str, _Episode] = {}
        self.predictions: dict[str, Prediction | None] = {}
        self.faults = {name: FaultLog(log, signal=name, end_level="error") for name in self.checked}
        #: Episodes begun since start (a virtual sensor stood in).
        self.count = 0

    def report_to(self, sink: EventSink) -> None:
        for fault in self.faults.values():
            fault.sink = sink

    def tolerance(self, prediction: Prediction) -> float:
        return max(self.settings.k_sigma * prediction.sigma, self.settings.min_tolerance)

    def judge(
        self, t_s: float, readings: dict[str, Reading], read: Mapping[str, float | None]
    ) -> dict[str, Reading]:
        """The readings to use this tick, wrong inputs replaced by their predictions (``read``: what each read)."""
        check = self.check
        values = {name: r.value for name, r in readings.items()}
        z = check.features(values)
        suspect = {n for n in self.checked if n in self.episodes}
        bad = {n for n, r in readings.items() if r.health is not Health.OK} | suspect
        ok = check.usable(z, bad)
        candidates = [n for n in self.checked if n not in bad]
        predictions = self._predictions(z, ok)
        while candidates:
            scores = {
                name: self._score(name, values[name], p)
                for name in candidates
                if (p := predictions[name]) is not None
            }
            worst = max(scores, key=scores.__getitem__, default=None)
            if worst is None or scores[worst] <= 1.0:
                break
            p = predictions[worst]
            assert p is not None
            self._begin(t_s, worst, read.get(worst), p, "disagrees with the other sensors", ok)
            candidates.remove(worst)
            ok[check.model.signals.index(worst)] = False
            predictions = self._predictions(z, ok)
        out = dict(readings)
        for name in self.checked:
            reading = readings[name]
            p = predictions[name]
            if name in candidates:
                self._learn(name, values[name], p)
                continue
            if name not in self.episodes and reading.health is not Health.OK and p is not None:
                self._begin(t_s, name, read.get(name), p, reading.reason, ok)
            episode = self.episodes.get(name)
            if episode is None:
                continue
            if p is None:
                # Nothing left to predict it from: as without a consistency model. A reading that
                # passes its own checks is used (nothing can confirm or refute it); else it is
                # held at what the model last used, and faulted (the axes freeze, then ramp).
                if reading.health is Health.OK:
                    self._end(t_s, name, reading.value, None)
                    continue
                last = self.monitors[name].last_good
                out[name] = Reading(last, Health.FAULTED, f"no prediction: {episode.reason}")
                self.monitors[name].rebase(out[name], last)
                continue
            agrees = reading.health is Health.OK and self._score(name, reading.value, p) <= 1.0
            episode.agreeing = episode.agreeing + 1 if agrees else 0
            if episode.agreeing >= self.settings.confirm_ticks:
                self._end(t_s, name, reading.value, p)
                self._learn(name, reading.value, p)
                continue
            estimate = p.value + self.residue.get(name, 0.0)
            why = f"estimated from the other sensors: {episode.reason}"
            out[name] = Reading(estimate, Health.ESTIMATED, why)
            now = read.get(name)
            reference = now if now is not None and math.isfinite(now) else out[name].value
            self.monitors[name].rebase(out[name], reference)
        self.predictions = predictions
        if any(out[n] is not readings[n] for n in self.checked):
            # The low-passes take what was used.
            z = check.features({n: r.value for n, r in out.items()})
        check.advance(z)
        return out

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

    def _score(self, name: str, value: float, p: Prediction) -> float:
        """How far ``value``'s residue jumped from its recent level, in tolerances (above 1: wrong)."""
        residue = value - p.value
        return abs(residue - self.residue.get(name, residue)) / self.tolerance(p)

    def _learn(self, name: str, value: float, p: Prediction | None) -> None:
        if p is None or not math.isfinite(value):
            return
        r = value - p.value
        a = self._anchor_a
        self.residue[name] = a * self.residue[name] + (1 - a) * r if name in self.residue else r

    def _begin(
        self,
        t_s: float,
        name: str,
        value: float | None,
        p: Prediction,
        reason: str,
        ok: np.ndarray,
    ) -> None:
        self.episodes[name] = _Episode(t_s, reason)
        self.count += 1
        unit = self.units.get(name, "")
        self.faults[name].failed(
            "signal replaced by its prediction from the other sensors",
            read=_round(value),
            predicted=_round(p.value + self.residue.get(name, 0.0)),
            tolerance=_round(self.tolerance(p)),
            unit=unit,
            reason=reason,
            predicted_from=[
                s
                for s, good in zip(self.check.model.signals, ok, strict=True)
                if good and s != name
            ],
        )

    def _end(self, t_s: float, name: str, value: float, p: Prediction | None) -> None:
        episode = self.episodes.pop(name)
        self.faults[name].cleared(
            "signal agrees with the other sensors again: its readings are used"
            if p is not None
            else "signal passes its own checks again (no other sensors to judge it): its readings are used",
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
