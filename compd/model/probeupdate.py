"""Recursive Bayesian (Kalman) update of a model's linear parameters from sparse probe measurements.

Every compd model's output is linear in its sub-models' coefficients (issue
42; issue 35 item 2 for gains)::

    y(t) = f(t) + sum_i k_i u_i(t) + b = f(t) + x(t)' theta,   x = (u_1 .. u_n, 1),  theta = (k_1 .. k_n, b)

where ``k_i`` is sub-model ``i``'s static gain in the file (um per input
unit: a lag term's or a static gain's, as ``compd fit`` identified it),
``u_i = c_i / k_i`` its contribution per unit of it (:meth:`Prior.regressors`)
and ``f`` (um) what no coefficient scales (a residual model's term). The
file's model is ``theta0 = (k_1 .. k_n, 0)`` (a prior in gains: ``u_i = c_i``,
``theta0 = (1 .. 1, 0)``). The parameters follow a random
walk; a probe measures ``z = y + v``, ``v ~ N(0, R)``:

- time update over ``dt_s`` seconds: ``P += Q(dt_s)``, where
  ``Q(dt_s) = P0 * drift_um_per_sqrt_h^2 * dt_s / 3600 / (x' P0 x)``: the
  prior's shape, scaled so that the prediction at the probe's regressor may
  drift by ``drift_um_per_sqrt_h`` um per sqrt(hour);
- measurement update: innovation ``e = z - x' theta``, ``S = x' P x + R``,
  ``K = P x / S``, ``theta += K e`` and ``P -= (P x)(P x)' / S`` (Joseph's form
  ``(I - K x') P (I - K x')' + K R K'`` for this optimal ``K``).

Guard rails (issue 35 item 3):

- an innovation beyond ``reject_sigma`` * sqrt(S) and beyond ``reject_floor_um``
  (the model's structural error on a new programme is not a mis-probe) is
  flagged and not used,
  unless the next probe confirms it (also beyond, same sign): then the bias's
  variance is widened so the confirmed innovation is one sigma
  (``P_bb += e^2 - R - x' P x``: the random walk did not allow for a shift of
  that size) and both probes are taken in time order;
- each parameter but the bias is clipped to its rails
  (:func:`parameter_bounds`: a gain to ``gain_bounds``, a coefficient to
  :data:`COEFFICIENT_BOUND_SD` prior standard deviations of the file's), the
  bias keeping the updated prediction at the probe; the updated prediction at the probe
  may not be further than ``max_departure_um`` from the calibration model's
  (``x' theta0``): the bias, the one parameter with no guard rail, takes up
  the excess;
- a measured value beyond :func:`max_probe_um` (1 mm, or 10 times the
  calibration's largest output) is not a thermal error: refused with a
  :class:`ModelError` before anything moves;
- a person may take a shift the rails would not (``accept_shift``): the
  probe is taken at once as a confirmed one, the departure rail widened to
  its innovation;
- an update whose parameters or covariance are not finite is taken back
  and refused with a :class:`ModelError` (the state before it is kept);
- given the regressors of the time since the last probe (``recent``), the
  update's step is shortened so that the departure bound holds over them
  too and no prediction there moves by more than :data:`REACH` times the
  innovation: a probe says how far the model is off at one instant, and an
  update that fits it by moving gains the calibration could not tell apart
  (temperatures that move together) swings the prediction elsewhere.

One probe costs O(p^2 + m p) for p parameters and m recent rows (about 0.1 ms
at 80 parameters in numpy).
numpy only: no files, no logging; the daemon steps it as ``compd compare
--probe-every`` does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np

from compd.errors import ModelError
from compd.model.probecovariance import DriftingCovariance
from compd.model.probesettings import ProbeSettings, max_probe_um, parameter_bounds
from compd.model.updateprior import BIAS, Prior

__all__ = ["BIAS", "PendingProbe", "Prior", "ProbeStep", "ProbeUpdater"]

#: An update may move a prediction since the last probe by at most this many times the
#: probe's innovation (chosen on the random machines: the worst machine at 2 h -62.7 -> -8.7 points).
REACH = 2.0
ProbeResult = Literal["accepted", "flagged", "confirmed", "rejected"]


@dataclass(frozen=True)
class ProbeStep:
    """One probe as the update took it; innovations in um (measured minus predicted)."""

    time_s: float
    measured_um: float
    predicted_um: float
    predicted_sd_um: float
    innovation_before_um: float
    innovation_after_um: float
    result: ProbeResult
    bounded: bool = False


@dataclass
class PendingProbe:
    """A flagged probe held until the next one confirms or drops it (persisted with the state)."""

    time_s: float
    x: np.ndarray
    fixed_um: float
    measured_um: float
    innovation_um: float


@dataclass
class ProbeUpdater:
    """The running update: parameters ``theta`` and covariance ``P``, stepped probe by probe.

    Call :meth:`probe` in time order with the probe's regressor ``x``
    (contributions at the probe instant, then 1), the unscaled part ``fixed_um``
    and the measured value; :meth:`predict` gives the output of the current
    parameters for any regressors.
    """

    prior: Prior
    settings: ProbeSettings
    theta: np.ndarray = field(init=False)
    #: ``P``, kept so that a probe costs one pass over it (:mod:`compd.model.probecovariance`).
    _p: DriftingCovariance = field(init=False, repr=False)
    last_time_s: float | None = field(init=False, default=None)
    #: Up to when the random walk has been added to ``covariance`` (the last probe taken).
    drifted_to_s: float | None = field(init=False, default=None)
    _recent: np.ndarray | None = field(init=False, default=None, repr=False)
    pending: PendingProbe | None = field(init=False, default=None)

    def __post_init__(self) -> None:
        self.theta = self.prior.mean
        self.covariance = self.prior.covariance.copy()

    @property
    def covariance(self) -> np.ndarray:
        """The parameters' covariance ``P`` (a new array: change it by assigning)."""
        return self._p.matrix()

    @covariance.setter
    def covariance(self, value: np.ndarray) -> None:
        self._p = DriftingCovariance.of(value, self.prior.covariance)

    def parameter_variance(self, x: np.ndarray) -> float:
        """``x' P x`` (um^2): the prediction's variance at ``x`` from the parameters' uncertainty."""
        return float(x @ self._p.times(x))

    def snapshot(self) -> tuple[object, ...]:
        """What a probe changes: :meth:`put_back` returns the update to it (snapshots may nest
        while nothing changes between them: a learner's around its update's own)."""
        return (
            self.theta.copy(),
            self._p,
            self._p.snapshot(),
            self._p.drift_weight,
            self.last_time_s,
            self.drifted_to_s,
            self.pending,
        )

    def put_back(self, snapshot: tuple[object, ...]) -> None:
        theta, p, token, weight, last, drifted, pending = snapshot
        assert isinstance(p, DriftingCovariance) and isinstance(token, int)
        p.put_back(token)
        p.drift_weight = weight  # type: ignore[assignment]
        self.theta, self._p = theta, p  # type: ignore[assignment]
        self.last_time_s, self.drifted_to_s, self.pending = last, drifted, pending  # type: ignore[assignment]

    def finite(self) -> bool:
        """Whether the parameters and their covariance are all finite numbers."""
        return bool(np.all(np.isfinite(self.theta))) and self._p.finite()

    def predict(self, x: np.ndarray, fixed_um: np.ndarray | float = 0.0) -> np.ndarray:
        """``f + x' theta`` (um) for one regressor (p,) or many (N, p)."""
        predicted: np.ndarray = np.asarray(fixed_um) + np.asarray(x) @ self.theta
        return predicted

    def probe(
        self,
        time_s: float,
        x: np.ndarray,
        measured_um: float,
        fixed_um: float = 0.0,
        recent: np.ndarray | None = None,
        *,
        accept_shift: bool = False,
    ) -> list[ProbeStep]:
        """Take one probe at ``time_s`` (s, not before the last); the steps taken, in time order.

        One step normally; two when this probe confirms a flagged one (the
        flagged one first, taken now). ``recent``: regressors (m, p) of the
        time since the last probe; the departure bound holds over them too
        (an update that fits the probe by moving gains the calibration could
        not tell apart would swing the prediction elsewhere).
        ``accept_shift``: a person says the machine moved: a probe beyond the
        rejection threshold is taken at once, as a confirmed one, and the
        departure rail gives way to its innovation.

        A :class:`ModelError` (a value beyond :func:`max_probe_um`, a touch
        out of order, an update that is not finite) leaves the state as it was.
        """
        x = np.array(x, dtype=float)  # the update's own copy: products with it are kept
        if x.shape != self.theta.shape:
            raise ModelError(f"a probe's regressor needs {self.theta.size} values, has {x.shape}")
        if not (np.all(np.isfinite(x)) and np.isfinite(measured_um)):
            raise ModelError("a probe's regressor and measured value must be finite")
        bound = max_probe_um(self.prior)
        if abs(measured_um) > bound:
            raise ModelError(
                f"a probe of {measured_um:g} um is beyond what a thermal error can be "
                f"({bound:g} um: 1 mm, or 10 times the calibration's largest output): "
                "check the value and its unit (um)"
            )
        if self.last_time_s is not None and time_s < self.last_time_s:
            raise ModelError(
                f"probes must come in time order: {time_s} s after {self.last_time_s} s"
            )
        before, settings = self.snapshot(), self.settings
        try:
            with np.errstate(all="ignore"):  # an overflow is refused below, not warned about
                steps = self._probe(time_s, x, measured_um, fixed_um, recent, accept_shift)
            if not self.finite():
                raise ModelError("the update gave parameters that are not finite numbers")
        except BaseException:
            self.put_back(before)
            raise
        finally:
            self.settings = settings
        return steps

    def _probe(
        self,
        time_s: float,
        x: np.ndarray,
        measured_um: float,
        fixed_um: float,
        recent: np.ndarray | None,
        accept_shift: bool,
    ) -> list[ProbeStep]:
        self._recent = None if recent is None else np.asarray(recent, dtype=float)
        self.last_time_s = time_s
        predicted = float(fixed_um + x @ self.theta)
        # x' Q(dt) x is the drift over dt by Q's construction; P itself drifts only when a
        # probe is taken, so a flagged one changes nothing at all.
        variance = self.parameter_variance(x) + self._drift_variance(time_s)
        innovation = measured_um - predicted
        sd = float(np.sqrt(variance + self.settings.probe_noise_um**2))
        beyond = abs(innovation) > max(
            self.settings.reject_sigma * sd, self.settings.reject_floor_um
        )
        pending, self.pending = self.pending, None
        if beyond and accept_shift:  # a person vouches for it: confirmed at once, rail widened
            departure = abs(innovation) + self.settings.max_departure_um
            self.settings = replace(self.settings, max_departure_um=departure)
            r = self.settings.probe_noise_um**2
            self._widen_bias(max(0.0, innovation * innovation - r - variance))
            sd = self.predicted_sd_um(x, time_s)
            step = self._take(time_s, x, fixed_um, measured_um, predicted, sd, "confirmed")
            return [*self._dropped(pending), step]
        if not beyond:
            step = self._take(time_s, x, fixed_um, measured_um, predicted, sd, "accepted")
            return [*self._dropped(pending), step]
        if pending is None or np.sign(pending.innovation_um) != np.sign(innovation):
            self.pending = PendingProbe(time_s, x, fixed_um, measured_um, innovation)
            held = ProbeStep(time_s, measured_um, predicted, sd, innovation, innovation, "flagged")
            return [*self._dropped(pending), held]
        # Confirmed: the machine moved further than the random walk allows (a shift: a crash,
        # a re-clamped part). The bias's variance is widened so this innovation is one sigma,
        # then both probes are taken in time order.
        r = self.settings.probe_noise_um**2
        self._widen_bias(max(0.0, innovation * innovation - r - variance))
        first = self._pending_step(pending)
        predicted = float(fixed_um + x @ self.theta)
        sd = self.predicted_sd_um(x, time_s)
        return [first, self._take(time_s, x, fixed_um, measured_um, predicted, sd, "confirmed")]

    def _widen_bias(self, variance_um2: float) -> None:
        """Widen the bias's variance (a confirmed shift the random walk did not allow for)."""
        self._p.add_to_last(variance_um2)

    def _pending_step(self, pending: PendingProbe) -> ProbeStep:
        """A flagged probe taken once confirmed."""
        predicted = float(pending.fixed_um + pending.x @ self.theta)
        sd = self.predicted_sd_um(pending.x, pending.time_s)
        return self._take(
            pending.time_s,
            pending.x,
            pending.fixed_um,
            pending.measured_um,
            predicted,
            sd,
            "confirmed",
        )

    def _dropped(self, pending: PendingProbe | None) -> list[ProbeStep]:
        """A flagged probe the next one did not confirm: rejected for good."""
        if pending is None:
            return []
        e = pending.innovation_um
        predicted = pending.measured_um - e
        return [
            ProbeStep(
                pending.time_s, pending.measured_um, predicted, float("nan"), e, e, "rejected"
            )
        ]

    def predicted_sd_um(self, x: np.ndarray, time_s: float) -> float:
        """The innovation's predicted standard deviation at ``x`` and ``time_s`` (um):
        the parameters' uncertainty, their drift since the last probe taken, the probe noise."""
        variance = self.parameter_variance(x) + self._drift_variance(time_s)
        return math.sqrt(variance + self.settings.probe_noise_um**2)

    def _drift_variance(self, time_s: float) -> float:
        """``x' Q(dt) x`` (um^2): the drift of the prediction since the last probe taken."""
        dt_s = 0.0 if self.drifted_to_s is None else max(0.0, time_s - self.drifted_to_s)
        return self.settings.drift_um_per_sqrt_h**2 * dt_s / 3600.0

    def _drift(self, x: np.ndarray, time_s: float) -> None:
        """``P += Q(dt)`` up to ``time_s``: the prior's shape, the prediction at ``x`` drifting as configured."""
        dt_s = 0.0 if self.drifted_to_s is None else time_s - self.drifted_to_s
        self.drifted_to_s = time_s
        if dt_s <= 0.0 or self.settings.drift_um_per_sqrt_h <= 0.0:
            return
        scale = self._p.prior_quadratic(x)
        if scale <= 0.0:
            return
        self._p.drift_weight += self.settings.drift_um_per_sqrt_h**2 * dt_s / 3600.0 / scale

    def _take(
        self,
        time_s: float,
        x: np.ndarray,
        fixed_um: float,
        measured_um: float,
        predicted_um: float,
        sd_um: float,
        result: ProbeResult,
    ) -> ProbeStep:
        """The time update to ``time_s``, the Kalman measurement update, then the rails."""
        self._drift(x, time_s)
        before = self.theta.copy()
        r = self.settings.probe_noise_um**2
        px = self._p.times(x)
        s = float(x @ px) + r
        if not math.isfinite(s):  # an overflow: the step would be 0 * inf
            raise ModelError("the update gave parameters that are not finite numbers")
        innovation = measured_um - predicted_um
        self.theta = self.theta + px * (innovation / s)
        # With the optimal gain k = P x / s, Joseph's form (I - k x') P (I - k x')' + r k k'
        # is P - (P x)(P x)' / s: one rank-one product, symmetric as the outer product of one
        # vector with itself, made in place (a new p x p array per probe costs more than the
        # arithmetic). The drift part of P is not touched (probecovariance).
        try:
            self._p.downdate(px / math.sqrt(s))
        except ValueError as error:
            raise ModelError("the update gave parameters that are not finite numbers") from error
        # A gain clipped to its rails would take back part of the update at this probe: the
        # bias (no rail) keeps the updated prediction here.
        updated = float(x @ self.theta)
        low, high = parameter_bounds(self.prior, self.settings)
        np.clip(self.theta[:-1], low, high, out=self.theta[:-1])
        self.theta[-1] += updated - float(x @ self.theta)
        calibration = float(x @ self.prior.mean)
        departure = float(x @ self.theta) - calibration
        bound = self.settings.max_departure_um
        bounded = abs(departure) > bound
        if bounded:
            self.theta[-1] -= departure - np.copysign(bound, departure)
        if self._recent is not None and len(self._recent):
            step = self._within_bound(self._recent, before)
            step *= self._within_reach(self._recent, innovation, before)
            bounded = bounded or step < 1.0
        after = measured_um - float(fixed_um + x @ self.theta)
        return ProbeStep(
            time_s, measured_um, predicted_um, sd_um, innovation, after, result, bounded
        )

    def _within_reach(self, rows: np.ndarray, innovation: float, before: np.ndarray) -> float:
        """Shorten this update's step so it moves no recent prediction by more than ``REACH`` |e|.

        A probe tells how far the model is off at its instant (``e``, or the
        probe noise if larger); an update that moves the prediction elsewhere
        in the time since the last probe by more than ``REACH`` times that is
        moving gains along directions the calibration could not tell apart.
        Returns the share of the step kept.
        """
        delta = self.theta - before
        cap = REACH * max(abs(innovation), self.settings.probe_noise_um)
        largest = float(np.max(np.abs(rows @ delta)))
        if largest <= cap:
            return 1.0
        a = cap / largest
        self.theta = before + a * delta
        return a

    def _within_bound(self, rows: np.ndarray, before: np.ndarray) -> float:
        """Shorten this update's step so the bound holds over ``rows``; the share of the step kept.

        ``theta = before + a (theta - before)`` with the largest ``a`` in
        [0, 1] for which every row's departure from the calibration model
        stays within the bound (or, where ``before`` was already beyond it,
        does not grow).
        """
        mean = self.prior.mean
        start = rows @ (before - mean)
        move = rows @ (self.theta - before)
        end = start + move
        limit = np.maximum(self.settings.max_departure_um, np.abs(start))
        over = np.abs(end) > limit
        if not np.any(over):
            return 1.0
        share = (np.sign(end[over]) * limit[over] - start[over]) / move[over]
        a = float(np.clip(np.min(share), 0.0, 1.0))
        self.theta = before + a * (self.theta - before)
        return a
