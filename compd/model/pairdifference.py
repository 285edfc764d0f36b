"""The usual difference of two sensors of one point: their offsets and the difference of their lags.

Two Pt100s at one point read ``x1`` and ``x2``. Their difference
``d = x1 - x2`` is, fault-free::

    d = offset + lag_s * rate + noise

``offset``: their class-A offsets; ``lag_s``: the difference of their lags
(s; a first-order sensor reads ``tau * rate`` behind a ramp); ``rate``: the
point's rate (unit/s), smoothed over :data:`RATE_TAU_S` from the two
readings (a step of one of them, a fault, is no move of the point). What is
left, :meth:`PairDifference.excess`, is what a fault looks like
(:mod:`compd.service.loop.redundancy` judges it).

``offset`` and ``lag_s`` are fitted by least squares over the first
:data:`BASELINE_S` (weighted over :data:`LAG_TAU_S`, ``lag_s`` shrunk to 0
where the rate hardly varied: a steady ramp cannot tell an offset from a
lag); then ``lag_s`` is followed over :data:`LAG_TAU_S` and ``offset`` only
where the caller says the pair agrees (:meth:`PairDifference.settle`, over
:data:`BASELINE_TAU_S`), so that a drift never becomes the usual.

Pure numerics: no clock, no I/O.
"""

from __future__ import annotations

import math

#: The usual offset and lag are first fitted over this many seconds of readings (s).
BASELINE_S = 600.0
#: Two sensors of one point moving apart by more than this (x tolerance) in one tick: a step.
STEP = 0.3
#: The pair's temperature rate is smoothed over this long (s) to take off the difference of lags.
RATE_TAU_S = 30.0
#: Then the offset follows the difference this slowly (s), and only while the pair agrees.
BASELINE_TAU_S = 8 * 3600.0
#: The difference of the two sensors' lags is learnt over this long (s), while the pair agrees...
LAG_TAU_S = 3600.0
#: ...and never beyond this (s): a Pt100's lag is tens of seconds.
MAX_LAG_DIFFERENCE_S = 120.0
#: How well the difference of lags is known (s): this before a transient taught it, and
#: never better than the floor (a lag is first-order only roughly); a check of the excess
#: widens by it times the rate.
LAG_PRIOR_S = 40.0
LAG_FLOOR_S = 5.0
#: The pair's difference around its lag model, for the uncertainty of the lag (unit).
LAG_NOISE = 0.03
_RIDGE = (LAG_NOISE / LAG_PRIOR_S) ** 2


class PairDifference:
    """The fault-free difference of two sensors of one point, learnt as they read; see the module."""

    def __init__(self, period_s: float, tolerance: float) -> None:
        self.period_s = period_s
        #: A pair further apart than this when learnt has no usual offset (it is taken as 0).
        self.tolerance = tolerance
        #: The usual difference (unit), None until learnt.
        self.offset: float | None = None
        #: The difference of the two sensors' lags (s).
        self.lag_s = 0.0
        #: The point's rate (unit/s, smoothed).
        self.rate = 0.0
        self._last: tuple[float, float] | None = None
        #: Sums weighted over :data:`LAG_TAU_S` of 1, r, r^2, d, r d (r: the rate, d: the difference).
        self._n = self._r = self._rr = self._d = self._rd = 0.0
        self._learnt_s = 0.0

    def excess(self, d: float) -> float:
        """``d`` less its usual value, ``offset + lag_s * rate`` (unit); needs :attr:`offset`."""
        assert self.offset is not None
        return d - self.offset - self.lag_s * self.rate

    def settle(self, d: float) -> None:
        """Let the offset follow ``d`` over :data:`BASELINE_TAU_S` (the caller: the pair agrees)."""
        assert self.offset is not None
        a = math.exp(-self.period_s / BASELINE_TAU_S)
        self.offset = a * self.offset + (1.0 - a) * d

    def follow(self, x1: float, x2: float) -> None:
        """Smooth the pair's rate (unit/s) over :data:`RATE_TAU_S`: per tick, the mean of the two
        sensors' moves, or the smaller where they differ by more than :data:`STEP` x the
        tolerance (a step of one of them is no move of the point)."""
        if self._last is not None:
            d1, d2 = x1 - self._last[0], x2 - self._last[1]
            step = abs(d1 - d2) > STEP * self.tolerance
            smaller = d1 if abs(d1) < abs(d2) else d2
            move = smaller if step else (d1 + d2) / 2
            a = math.exp(-self.period_s / RATE_TAU_S)
            self.rate = a * self.rate + (1 - a) * move / self.period_s
        self._last = (x1, x2)

    @property
    def lag_uncertainty_s(self) -> float:
        """How well :attr:`lag_s` is known (s), from how much the rate varied while it was learnt."""
        spread = self._n * (self._rate_variance() + _RIDGE)
        if spread <= 0:
            return LAG_PRIOR_S
        return max(LAG_FLOOR_S, min(LAG_PRIOR_S, 3 * LAG_NOISE / math.sqrt(spread)))

    def _rate_variance(self) -> float:
        if self._n <= 0:
            return 0.0
        mean = self._r / self._n
        return max(0.0, self._rr / self._n - mean * mean)

    def learn(self, d: float) -> None:
        """Add ``d`` to the sums, weighted over :data:`LAG_TAU_S`, and fit the offset and the lag.

        ``d ~ offset + lag_s * rate`` by least squares, the lag shrunk to 0
        where the rate hardly varied (ridge: a steady ramp cannot tell an
        offset from a lag). Sensors of different lags read a transient
        differently, the slower one behind by its lag times the rate: that
        is no fault; what is left after it is.
        """
        a, r = math.exp(-self.period_s / LAG_TAU_S), self.rate
        self._n = a * self._n + 1.0
        self._r = a * self._r + r
        self._rr = a * self._rr + r * r
        self._d = a * self._d + d
        self._rd = a * self._rd + r * d
        if self.offset is not None:
            # The lag with the offset as it is: the offset moves only in :meth:`settle`.
            lag = (self._rd - self.offset * self._r) / (self._rr + self._n * _RIDGE)
            self.lag_s = max(-MAX_LAG_DIFFERENCE_S, min(MAX_LAG_DIFFERENCE_S, lag))
            return
        self._learnt_s += self.period_s
        if self._learnt_s < BASELINE_S:
            return
        mean_r, mean_d = self._r / self._n, self._d / self._n
        covariance = self._rd / self._n - mean_r * mean_d
        lag = covariance / (self._rate_variance() + _RIDGE)
        self.lag_s = max(-MAX_LAG_DIFFERENCE_S, min(MAX_LAG_DIFFERENCE_S, lag))
        offset = mean_d - self.lag_s * mean_r
        # Two sensors at one point agree within the tolerance: a pair further apart from the
        # start has no usual offset to learn, and is a fault now.
        self.offset = offset if abs(offset) <= self.tolerance else 0.0
