"""A slow departure of a residue from where it was: a two-sided CUSUM in the calibration's units.

A sensor that drifts (a Pt100 whose insulation absorbs moisture, a loose
terminal warming) passes every check that compares it with its own recent
past: the level of the last minutes moves along with it. Against its
prediction from the other sensors (:mod:`compd.model.consistency`) it does
not: its residue ``r`` (reading minus prediction) moves away from a reference
``r_ref`` (the residue of the signals' hour-long averages, so that the
reference follows the prediction's own slow bias, which the calibration
measured as ``sigma``: the RMS change of the residue over an hour).

Page's CUSUM on the standardised departure ``g = (r - r_ref) / sigma``, per
tick of ``dt`` hours::

    S+ = max(0, S+ + (g - k) dt)        S- = max(0, S- + (-g - k) dt)

alarms once ``S+`` or ``S-`` passes ``h`` (sigma-hours). ``k`` (in sigmas) is
the departure tolerated for ever: the calibration's own residue rarely
leaves ``r_ref`` by more; a drift of ``d`` per hour leaves it by about
``d * 1 h`` once the reference lags a full hour behind, so drifts faster than
about ``k * sigma`` per hour are caught, and a step of ``a`` sigmas above
``k`` after ``h / (a - k)`` hours. The time the statistic last left zero is
where the departure began (the change point), and the level the residue had
then is what a stand-in carries on with.

Pure numpy: the caller passes each tick's departures.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class CusumSettings:
    """The allowance ``k`` (sigmas) and the alarm threshold ``h`` (sigma-hours)."""

    k_sigma: float = 3.0
    h_sigma_h: float = 0.25


def smallest_step_sigma(settings: CusumSettings, reference_tau_h: float = 1.0) -> float:
    """The smallest persistent step (sigmas) the CUSUM catches against a reference that follows
    it with time constant ``reference_tau_h``: the departure ``a exp(-t / tau)`` sums to
    ``tau (a - k - k ln(a / k))`` while above ``k``, which must reach ``h`` (bisection)."""
    k, h = settings.k_sigma, settings.h_sigma_h

    def summed(a: float) -> float:
        return reference_tau_h * (a - k - k * math.log(a / k))

    low, high = k, k + h / reference_tau_h + 10.0 * k
    for _ in range(60):
        mid = 0.5 * (low + high)
        low, high = (mid, high) if summed(mid) < h else (low, mid)
    return high


class DriftCusum:
    """Two-sided CUSUMs of ``n`` standardised departures, stepped once a tick."""

    def __init__(self, n: int, period_s: float, settings: CusumSettings = CusumSettings()) -> None:
        self.settings = settings
        self.dt_h = period_s / 3600.0
        self.high = np.zeros(n)
        self.low = np.zeros(n)

    def step(self, g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Take this tick's departures ``g`` (sigmas; NaN: not judged, held); returns which
        left zero this tick (a departure begins) and which passed the threshold."""
        k = self.settings.k_sigma
        judged = np.isfinite(g)
        g = np.where(judged, g, 0.0)
        was_zero = (self.high == 0.0) & (self.low == 0.0)
        high = np.maximum(0.0, self.high + (g - k) * self.dt_h)
        low = np.maximum(0.0, self.low + (-g - k) * self.dt_h)
        self.high = np.where(judged, high, self.high)
        self.low = np.where(judged, low, self.low)
        departed = was_zero & ((self.high > 0.0) | (self.low > 0.0))
        alarmed = np.maximum(self.high, self.low) > self.settings.h_sigma_h
        return departed, alarmed

    @property
    def statistic(self) -> np.ndarray:
        """The larger of the two sums per departure (sigma-hours)."""
        return np.maximum(self.high, self.low)

    def reset(self) -> None:
        """Back to zero: after an alarm is acted on (its departures were one fault's)."""
        self.high[:] = 0.0
        self.low[:] = 0.0
