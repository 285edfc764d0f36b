"""What the other sensors cannot verify: per model input, the wrong reading no check catches, in um of offset.

A reading that is wrong by less than what its detector can see passes every
check, and the model turns it into offset. The detector's threshold is in the
input's unit (the plausibility check's tolerance ``max(k_sigma * sigma,
min_tolerance)`` in degC, :mod:`compd.service.loop.plausibility`); what matters
at the tool is that threshold times the model's static sensitivity to the
input, per axis::

    undetectable_um[input, axis] = threshold[input] * |S[input, axis]|
    S[input, axis] = sum_i gain_i * B_i(1) / A_i(1)     (the axis's sub-models that read the input;
                                                         minus the terms where it is subtracted)

(the steady-state gain: a wrong reading that persists moves the axis by this
much once the model has settled). Where sub-models are gated, each
combination of gate states is taken and the largest ``|S|`` kept; a gain
schedule's rows (``gain_sets``) likewise. A sub-model scaled by an axis
position (Pahk 2002's slope) contributes nothing at its reference position and
is left out. An input no detector can judge (no consistency prediction, no
redundant partner) has an infinite threshold: whatever it reads is believed.

Where ``undetectable_um`` exceeds the axis's tolerance (the accuracy the
compensation promises, :func:`default_tolerance_um`), the input cannot be
verified to that accuracy: a second sensor beside it (a redundant pair) or
probes on the axis are the remedy. This is a fact about information, not a
fault: it is said at commissioning and in the status, not in the status word.

The threshold comes from one function, a :data:`Detector` (input name ->
:class:`Detection`): :func:`plausibility_detector` is today's; another
detector (a CUSUM on the residue) plugs in the same way.

Pure numpy; no files, no logs.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from compd.model.compiled import CompiledModel
from compd.model.consistency import ConsistencyCheck, ConsistencyModel
from compd.model.drift import CusumSettings, smallest_step_sigma

#: The default tolerance of an axis is this many times the calibration's RMS residue of its
#: output (the accuracy the fit itself promises)...
TOLERANCE_RMS_FACTOR = 3.0
#: ...and never below this (um): a probe's or a sensor's own noise.
MIN_TOLERANCE_UM = 1.0
#: The tolerance of an axis whose model file records no calibration residue (um).
FALLBACK_TOLERANCE_UM = 5.0
#: Gates beyond this many on one input's sub-models of one axis: the bound sum of |terms| is
#: taken instead of every combination of gate states.
MAX_GATE_COMBINATIONS_LOG2 = 10


@dataclass(frozen=True)
class Detection:
    """How small a wrong reading of one input its detector catches."""

    #: The smallest error caught, in the input's unit; ``math.inf``: nothing catches it.
    threshold: float
    #: What catches it ("the other sensors", "its redundant partner T_spindle_b_degC"), or why nothing does.
    by: str

    @property
    def verifiable(self) -> bool:
        return math.isfinite(self.threshold)


#: A detector: the :class:`Detection` of an input, by name.
Detector = Callable[[str], Detection]


def default_tolerance_um(calibration_rms_um: float | None) -> float:
    """An axis's tolerance (um) where the config gives none: ``max(3 x calibration RMS, 1 um)``, else 5 um."""
    if calibration_rms_um is None or not math.isfinite(calibration_rms_um):
        return FALLBACK_TOLERANCE_UM
    return max(TOLERANCE_RMS_FACTOR * calibration_rms_um, MIN_TOLERANCE_UM)


def plausibility_detector(
    consistency: ConsistencyModel | None,
    *,
    k_sigma: float,
    min_tolerance: float,
    available: Collection[str] | None = None,
    partners: Mapping[str, tuple[str, float]] | None = None,
    without: str = "the model file has no consistency model",
    drift: CusumSettings | None = None,
) -> Detector:
    """Today's detector: the plausibility tolerance from the signals ``available``, or a redundant pair's.

    An input's threshold is ``max(k_sigma * sigma, min_tolerance)`` where
    ``sigma`` is its held-out residue spread when predicted from the
    ``available`` signals (all the calibration logged, when None), widened as
    predictors are missing, exactly as the daemon's check computes it
    (:meth:`ConsistencyCheck.predict_all`); an input the others explain too
    little of (or no consistency model at all) has none. ``partners`` maps an
    input to its redundant partner and the pair's tolerance (the input's
    unit): the smaller threshold wins. ``without``: why nothing checks the
    inputs where ``consistency`` is None. ``drift``: the daemon's drift CUSUM
    (:mod:`compd.model.drift`), which catches a persistent step of
    :func:`smallest_step_sigma` sigmas with no ``min_tolerance`` floor: the
    smaller threshold wins. (A drift slower than about ``drift.k_sigma`` sigmas
    an hour is caught only once it is that far off: the threshold is where
    a slow drift is caught, not how fast.)
    """
    step = math.inf if drift is None else smallest_step_sigma(drift)
    thresholds: dict[str, float] = {}
    if consistency is not None:
        read = set(consistency.signals if available is None else available)
        # The period sets the low-passes' steps only; the sigmas do not depend on it.
        check = ConsistencyCheck(consistency, 1.0, frozenset(read))
        ok = np.array([name in read for name in consistency.signals])
        _, sigmas = check.predict_all(np.asarray(consistency.mean, dtype=float), ok)
        for name, sigma in zip(consistency.checked, sigmas, strict=True):
            if name in read and math.isfinite(float(sigma)):
                instant = max(k_sigma * float(sigma), min_tolerance)
                thresholds[name] = min(instant, step * float(sigma))
    pairs = dict(partners or {})

    def detect(name: str) -> Detection:
        own = thresholds.get(name, math.inf)
        pair = pairs.get(name)
        if pair is not None and pair[1] < own:
            return Detection(pair[1], f"its redundant partner {pair[0]}")
        if math.isfinite(own):
            return Detection(own, "the other sensors")
        if consistency is None:
            return Detection(math.inf, f"nothing: {without}")
        if name not in consistency.checked:
            return Detection(math.inf, "nothing: the consistency model does not check it")
        return Detection(math.inf, "nothing: the signals read explain too little of it")

    return detect


def static_sensitivities(
    compiled: CompiledModel, gain_sets: Sequence[Mapping[str, float]] = ()
) -> dict[str, dict[str, float]]:
    """Per model output, per input signal: the largest static sensitivity (um per input unit, signed).

    ``gain_sets``: named gains (``gain_name`` -> value) a gain schedule may set;
    each is tried besides the model's own gains, and the largest ``|S|`` kept.
    """
    sets: list[Mapping[str, float]] = [{}, *gain_sets]
    out: dict[str, dict[str, float]] = {}
    for row, output in enumerate(compiled.output_names):
        members = np.flatnonzero(compiled.output_matrix[row])
        per_input: dict[str, list[tuple[int, float]]] = {}
        for i in members:
            sub = compiled.submodels[i]
            if sub.position is not None:
                continue  # a slope in um per mm: nothing at the reference position
            per_input.setdefault(sub.input.signal, []).append((int(i), 1.0))
            if sub.input.minus is not None:
                per_input.setdefault(sub.input.minus, []).append((int(i), -1.0))
        out[output] = {name: _largest(compiled, terms, sets) for name, terms in per_input.items()}
    return out


def _largest(
    compiled: CompiledModel, terms: list[tuple[int, float]], gain_sets: list[Mapping[str, float]]
) -> float:
    """The signed sensitivity of largest magnitude over gate states and gain sets."""
    best = 0.0
    for gains in gain_sets:
        values = []
        for i, sign in terms:
            sub = compiled.submodels[i]
            gain = gains.get(sub.gain_name, compiled.gain[i]) if sub.gain_name else compiled.gain[i]
            values.append(sign * float(gain) * compiled.discrete[i].static_gain())
        gates = sorted(
            {g for i, _ in terms if (g := compiled.submodels[i].gate) is not None}, key=repr
        )
        if len(gates) > MAX_GATE_COMBINATIONS_LOG2:
            total = sum(abs(v) for v in values)
            best = total if total > abs(best) else best
            continue
        for states in itertools.product((False, True), repeat=len(gates)):
            on = {g for g, state in zip(gates, states, strict=True) if state}
            total = sum(
                v
                for (i, _), v in zip(terms, values, strict=True)
                if (g := compiled.submodels[i].gate) is None or g in on
            )
            if abs(total) > abs(best):
                best = total
    return best


@dataclass(frozen=True)
class Unverifiable:
    """One input on one axis: what the detector cannot see of it, in um of offset."""

    input: str
    axis: str
    detection: Detection
    #: The model's static sensitivity of the axis's output to the input (um per input unit).
    um_per_unit: float
    #: ``threshold * |um_per_unit|``: the largest offset error a wrong reading can cause unseen.
    undetectable_um: float
    #: The axis's tolerance (um).
    tolerance_um: float

    @property
    def exceeds(self) -> bool:
        """Whether a wrong reading can move the axis beyond its tolerance unseen."""
        return self.undetectable_um > self.tolerance_um

    @property
    def remedy(self) -> str:
        """What to do about it ("" where nothing needs doing)."""
        if not self.exceeds:
            return ""
        return f"add a redundant sensor beside {self.input} / probes on {self.axis}"


def undetectable_error_um(
    compiled: CompiledModel,
    axes: Mapping[str, str],
    detect: Detector,
    tolerance_um: Mapping[str, float],
    gain_sets: Sequence[Mapping[str, float]] = (),
) -> list[Unverifiable]:
    """Per axis (``axes``: axis -> model output) and input it depends on: what ``detect`` cannot see, in um.

    Rows in the model's signal order, then axis order; an input of no static
    weight on an axis (a gate signal, a position) has no row for it.
    """
    sensitivity = static_sensitivities(compiled, gain_sets)
    rows = []
    for name in compiled.signals:
        detection = detect(name)
        for axis, output in axes.items():
            s = sensitivity.get(output, {}).get(name)
            if s is None or s == 0.0:
                continue
            rows.append(
                Unverifiable(
                    name,
                    axis,
                    detection,
                    s,
                    detection.threshold * abs(s),
                    tolerance_um[axis],
                )
            )
    return rows
