"""What a model's state can reach: a saved state beyond it was not produced by this model, and is refused.

Each sub-model is a DF2T filter ``b/a`` fed ``u = (signal - minus) - reference``
(:mod:`compd.model.compiled`). Its delay line obeys
``z_j(k) = sum_{m>j} (b_m u(k-m+j+1) - a_m y(k-m+j+1))``, so with ``|u| <= U``
and ``|y| <= G U`` every state is bounded by::

    |z_j| <= U * sum_{m>j} (|b_m| + |a_m| G)

``G`` is the larger of the steady-state gain ``|B(1)/A(1)|`` and the sum of
``|h|`` over the first :data:`~compd.model.limits.CHECK_SAMPLES` samples of
the impulse response (the two agree for the monotone lags of thermal
models; the sum catches an overshoot). ``U`` comes from the calibration's
``[min, max]`` of the sub-model's signals (``provenance.calibration.ranges``
of the model file), widened by :data:`INPUT_MARGIN` times their span either
way; a signal without a recorded range gets :data:`UNRANGED_INPUT`. Every
saved reference ("value at start", or the thermal zero shifted with the shop
air at start) must lie in the same widened range. Generous on purpose:
the check stops a state of 1e300 (a corrupted or crafted state file) from
driving the offsets to their clamp, not a state that is merely unusual.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from compd.errors import ModelError
from compd.model.compiled import CompiledModel, ModelState, qualified_names
from compd.model.dfilter import lfilter
from compd.model.limits import CHECK_SAMPLES

#: The calibration's span of a signal is widened by this many spans on each side.
INPUT_MARGIN = 10.0
#: The smallest span widened (input units): a signal constant in the calibration data.
MIN_SPAN = 1.0
#: The range of a signal the calibration did not record (input units, either sign).
UNRANGED_INPUT = 1e6


def check_reachable(
    compiled: CompiledModel, state: ModelState, ranges: Mapping[str, tuple[float, float]]
) -> None:
    """Raise ModelError naming the first sub-model whose state or reference it could not reach."""
    names = qualified_names(compiled)
    for row, sub in enumerate(compiled.submodels):
        low, high = _widened(ranges, sub.input.signal, sub.input.minus)
        fixed = compiled.fixed_reference[row]
        reference = float(state.reference[row])
        # A fixed reference (the thermal zero) is what the runner subtracts too, shifted at
        # start with the shop air: a saved one outside the inputs' range was never produced.
        if not low <= reference <= high:
            raise ModelError(
                f"the saved input reference of {names[row]} is {reference:.6g}, outside "
                f"[{low:.6g}, {high:.6g}] (the calibration's range of its input, widened "
                f"{INPUT_MARGIN:g} times): not a state this model produced"
            )
        # |u| = |input - reference|: both in the range, or the model's own fixed reference.
        u_max = high - low if np.isnan(fixed) else max(abs(high - reference), abs(low - reference))
        bounds = u_max * _state_gains(compiled.b[row], compiled.a[row]) + 1e-9
        beyond = np.flatnonzero(~(np.abs(state.z[row]) <= bounds))
        if beyond.size:
            j = int(beyond[0])
            raise ModelError(
                f"the saved state z[{j}] of {names[row]} is {state.z[row, j]:.6g}; inputs within "
                f"[{low:.6g}, {high:.6g}] reach at most ±{bounds[j]:.6g}: not a state this model "
                "produced"
            )


def _widened(
    ranges: Mapping[str, tuple[float, float]], signal: str, minus: str | None
) -> tuple[float, float]:
    """The range of ``signal - minus``, widened by INPUT_MARGIN spans either way."""
    low, high = _range(ranges, signal)
    if minus is not None:
        minus_low, minus_high = _range(ranges, minus)
        low, high = low - minus_high, high - minus_low
    span = max(high - low, MIN_SPAN) * INPUT_MARGIN
    return low - span, high + span


def _range(ranges: Mapping[str, tuple[float, float]], signal: str) -> tuple[float, float]:
    if signal not in ranges:
        return -UNRANGED_INPUT, UNRANGED_INPUT
    low, high = ranges[signal]
    return float(min(low, high)), float(max(low, high))


def _state_gains(b: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Per delay-line state, its bound for a unit bound on the input (see the module's text)."""
    with np.errstate(all="ignore"):
        impulse = np.zeros(CHECK_SAMPLES)
        impulse[0] = 1.0
        l1 = float(np.sum(np.abs(lfilter(b, a, impulse)[0])))
        static = abs(float(b.sum() / a.sum()))
    gain = max(l1, static)
    terms = np.abs(b[1:]) + np.abs(a[1:]) * gain
    gains: np.ndarray = np.cumsum(terms[::-1])[::-1]
    return gains
