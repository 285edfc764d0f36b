"""The prior of the probe update (:mod:`compd.model.probeupdate`): the calibration's posterior, or a default.

Two forms of the parameters (issue 42):

- **the model's coefficients** (what ``compd fit`` stores now): each
  sub-model's static gain (um per input unit, a lag term's or a static
  gain's, as the fit identified it), then the bias (um). The regressor of a
  sub-model is its contribution per unit of its coefficient, so a term the
  calibration shrank to almost nothing can grow again when the machine says
  so. The covariance is the calibration's posterior of a ridge regression
  in standardised units (:func:`coefficient_prior`): narrow along the
  directions the calibration pinned, as wide as the prior allows along
  those it could not decide (inputs that move together, lag terms nothing
  excited);
- **gains on the file's sub-models** (files written before issue 42, and
  the default of a file without a prior): every gain 1, the contributions
  as the regressors (:func:`calibration_prior`, :func:`default_prior`).

Both widen the calibration's information by the residue's autocorrelation
(its effective sample size, Sokal's integrated autocorrelation time). numpy
only.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Literal

import numpy as np

from compd.errors import ModelError

#: Before the calibration every gain is 1 +- this (the ridge of :func:`calibration_prior`): the
#: default prior's gain sd, so the calibration's posterior is never wider than no calibration
#: in any gain. Chosen on the random machines (benchmarks/bench_probes.py, 1.0 and 0.3 tried:
#: at 2 h 0.3 halved the 5 % quantile of the change against open loop, -3.17 -> -1.67 points,
#: beating open loop as often, 79 -> 78 %).
DEFAULT_PRIOR_GAIN_SCALE = 0.3
#: The conservative prior of a model file without one: gain sd, and bias sd in calibration RMS.
DEFAULT_GAIN_SD = 0.3
DEFAULT_BIAS_SD_RMS = 2.0
#: The name of the bias parameter.
BIAS = "bias"
#: Before the calibration each coefficient, in standardised units (um per standard deviation
#: of its regressor over the calibration), is 0 +- this many standard deviations of the
#: calibration output: one input could explain all of it. What the calibration could not
#: decide keeps about that much room; the probe bank's ``narrow`` member takes a hundredth of
#: the variance (:data:`compd.model.probebank.MEMBERS`, where the choice was measured).
DEFAULT_COEFFICIENT_SCALE = 1.0


@dataclass(frozen=True, eq=False)
class Prior:
    """The parameters' prior: mean ``(1 .. 1, 0)``, ``covariance`` (p, p) in gain^2 and um^2.

    ``names``: each gain's sub-model, then :data:`BIAS`; ``residue_sigma_um``:
    the calibration residue's standard deviation; ``samples`` and
    ``effective_samples``: the calibration's length and its effective sample
    size (0 for a default prior); ``output_peak_um``: the largest
    ``|output|`` the calibration model gave over its calibration (0:
    unknown); ``source``: ``"calibration"`` (``compd fit`` stored it) or
    ``"default"`` (:func:`default_prior`); ``coefficients``: in the model's
    coefficients form, each sub-model's static gain in the file (um per
    input unit; the prior's mean), else None (gains, mean 1).
    """

    names: tuple[str, ...]
    covariance: np.ndarray
    residue_sigma_um: float
    samples: int = 0
    effective_samples: float = 0.0
    output_peak_um: float = 0.0
    source: Literal["calibration", "default"] = "calibration"
    coefficients: np.ndarray | None = None
    #: In the coefficients form, the calibration's posterior of gains on the sub-models (the
    #: update before issue 42: each coefficient moves in proportion to itself), in the
    #: coefficients' units; the bank's ``gains`` member starts from it. None: ``covariance``.
    gains_covariance: np.ndarray | None = None
    #: The calibration residue's transient variance (:func:`transient_variances`): pairs of a
    #: probe interval (s) and the variance (um^2) that does not persist over it; () unknown.
    transient_um2: tuple[tuple[float, float], ...] = ()

    def __post_init__(self) -> None:
        p = len(self.names)
        if self.covariance.shape != (p, p):
            raise ModelError(f"prior covariance must be {p} x {p}, is {self.covariance.shape}")
        if not np.all(np.isfinite(self.covariance)):
            raise ModelError("prior covariance must be finite")
        if self.coefficients is not None and (
            self.coefficients.shape != (p - 1,) or not np.all(np.isfinite(self.coefficients))
        ):
            raise ModelError(f"prior coefficients must be {p - 1} finite values")
        if self.gains_covariance is not None and (
            self.gains_covariance.shape != (p, p) or not np.all(np.isfinite(self.gains_covariance))
        ):
            raise ModelError(f"prior gains covariance must be {p} x {p} finite values")
        intervals = [pair[0] for pair in self.transient_um2]
        if not all(
            len(pair) == 2 and pair[0] > 0 and pair[1] >= 0 and np.all(np.isfinite(pair))
            for pair in self.transient_um2
        ) or intervals != sorted(set(intervals)):
            raise ModelError(
                "prior transient variances must be pairs of an interval (s, increasing, above 0) "
                "and a variance (um^2, 0 or more)"
            )

    def transient_variance_um2(self, interval_s: float) -> float:
        """The residue's variance that does not persist over ``interval_s`` (um^2), interpolated
        in :attr:`transient_um2` (0 at 0 s, the last value beyond the last interval); 0 unknown."""
        if not self.transient_um2 or not interval_s > 0:
            return 0.0
        intervals, variances = zip(*((0.0, 0.0), *self.transient_um2), strict=True)
        return float(np.interp(interval_s, intervals, variances))

    @property
    def form(self) -> Literal["coefficients", "gains"]:
        """What the parameters are: the model's coefficients, or gains on its sub-models."""
        return "gains" if self.coefficients is None else "coefficients"

    @property
    def mean(self) -> np.ndarray:
        """The file's model: its coefficients (or gains of 1), then a bias of 0."""
        theta = np.ones(len(self.names))
        if self.coefficients is not None:
            theta[:-1] = self.coefficients
        theta[-1] = 0.0
        return theta

    @property
    def units(self) -> np.ndarray:
        """Per parameter, the contribution (um) of one unit of it in the file: ``x = (c, 1) / units``.

        The coefficient itself where it is not 0 (its contribution per unit
        coefficient is the sub-model's unit-gain response); 1 for a gain, the
        bias, and a coefficient of exactly 0 (whose contribution is 0).
        """
        mean = self.mean
        units = np.where(mean != 0.0, mean, 1.0)
        units[-1] = 1.0
        return units

    @cached_property
    def _unit_row(self) -> list[float]:
        return [float(u) for u in self.units]

    def regressor_row(self, contributions_um: Sequence[float]) -> list[float]:
        """:meth:`regressors` of one tick in Python floats (the same divisions, so the same
        numbers): the tick enters no numpy."""
        units = self._unit_row
        row = [c / u for c, u in zip(contributions_um, units, strict=False)]
        row.append(1.0 / units[-1])
        return row

    def regressors(self, contributions_um: np.ndarray) -> np.ndarray:
        """The update's regressors from the sub-models' contributions (um): (S,) -> (S+1,), (N, S) -> (N, S+1)."""
        c = np.asarray(contributions_um, dtype=float)
        ones = np.ones((*c.shape[:-1], 1))
        x: np.ndarray = np.concatenate([c, ones], axis=-1) / self.units
        return x


def default_prior(names: tuple[str, ...], calibration_rms_um: float) -> Prior:
    """The conservative prior of a model file without one (issue 35 item 2).

    Every gain ``1 +- DEFAULT_GAIN_SD``, independent; the bias
    ``0 +- DEFAULT_BIAS_SD_RMS * calibration_rms_um``. ``names`` end with
    :data:`BIAS`.
    """
    if not names or names[-1] != BIAS:
        raise ModelError(f"a prior's parameters end with {BIAS!r}")
    sd = np.full(len(names), DEFAULT_GAIN_SD)
    sd[-1] = DEFAULT_BIAS_SD_RMS * calibration_rms_um
    return Prior(names, np.diag(sd**2), calibration_rms_um, source="default")


def calibration_prior(
    names: tuple[str, ...],
    contributions_um: np.ndarray,
    residue_um: np.ndarray,
    *,
    gain_scale: float | None = None,
) -> Prior:
    """The calibration's posterior as prior (issue 35 item 2).

    With ``X = [C, 1]`` (n, p) the calibration's contributions and a column of
    ones, ``s`` the residue's standard deviation and ``n_eff`` its effective
    sample size (:func:`effective_samples`)::

        P0 = ((n_eff / n) X'X / s^2 + L)^-1 = s^2 (n / n_eff) (X'X + (n / n_eff) s^2 L)^-1

    the ridge posterior of the regression of the output on its contributions,
    each sample worth ``n_eff / n`` of an independent one (a thermal fit's
    residue is strongly autocorrelated). ``L = diag(1 / gain_scale^2, ..., 0)``:
    before the calibration every gain is ``1 +- gain_scale``, the bias free.
    """
    c = np.asarray(contributions_um, dtype=float)
    e = np.asarray(residue_um, dtype=float).ravel()
    if c.ndim != 2 or c.shape[0] != e.size or c.shape[1] + 1 != len(names):
        raise ModelError(
            f"{len(names)} parameters need (n, {len(names) - 1}) contributions and n residues"
        )
    if e.size < 3:
        raise ModelError("a calibration prior needs at least 3 samples")
    x = np.column_stack([c, np.ones(e.size)])
    peak = float(np.max(np.abs(c.sum(axis=1))))
    sigma = float(np.std(e))
    sigma = max(sigma, 1e-6)
    n_eff = effective_samples(e)
    scale = DEFAULT_PRIOR_GAIN_SCALE if gain_scale is None else gain_scale
    ridge = np.full(len(names), 1.0 / scale**2)
    ridge[-1] = 0.0
    information = (n_eff / e.size) * (x.T @ x) / sigma**2 + np.diag(ridge)
    covariance = np.linalg.pinv(information, hermitian=True)
    covariance = 0.5 * (covariance + covariance.T)
    return Prior(names, covariance, sigma, int(e.size), float(n_eff), peak)


def coefficient_prior(
    names: tuple[str, ...],
    contributions_um: np.ndarray,
    residue_um: np.ndarray,
    coefficients: np.ndarray,
    *,
    scale: float | None = None,
    sample_time_s: float | None = None,
) -> Prior:
    """The calibration's posterior in the model's coefficients (issue 42).

    With ``B`` (n, S) the sub-models' unit responses over the calibration
    (contributions per unit coefficient, :attr:`Prior.units`), ``D`` their
    standard deviations, ``Z = [B D^-1, 1]``, ``s`` the residue's standard
    deviation and ``n_eff`` its effective sample size::

        P_z = ((n_eff / n) Z'Z / s^2 + diag(1 / tau^2, ..., 1 / tau^2, 0))^-1,   P = D^-1 P_z D^-1

    the ridge posterior in standardised units: before the calibration each
    standardised coefficient is ``0 +- tau``, ``tau = scale`` standard
    deviations of the calibration output (:data:`DEFAULT_COEFFICIENT_SCALE`);
    the bias free. The mean is the fitted model (``coefficients``), whatever
    ridge the fit itself used: the covariance says how far the calibration
    pinned each direction, wide where it could not (inputs that move
    together, slow lags a short calibration never excited). With
    ``sample_time_s`` (the residue's), also the residue's transient variance
    per probe interval (:func:`transient_variances`).
    """
    c = np.asarray(contributions_um, dtype=float)
    e = np.asarray(residue_um, dtype=float).ravel()
    k = np.asarray(coefficients, dtype=float)
    if (
        c.ndim != 2
        or c.shape[0] != e.size
        or c.shape[1] + 1 != len(names)
        or k.shape != (c.shape[1],)
    ):
        raise ModelError(
            f"{len(names)} parameters need (n, {len(names) - 1}) contributions, n residues and "
            f"{len(names) - 1} coefficients"
        )
    if e.size < 3:
        raise ModelError("a calibration prior needs at least 3 samples")
    shape = Prior(names, np.eye(len(names)), 1.0, coefficients=k)
    basis = shape.regressors(c)[:, :-1]
    sd = np.std(basis, axis=0)
    sd = np.where(sd > 0.0, sd, 1.0)
    z = np.column_stack([basis / sd, np.ones(e.size)])
    sigma = max(float(np.std(e)), 1e-6)
    n_eff = effective_samples(e)
    y = c.sum(axis=1) + e
    tau = (DEFAULT_COEFFICIENT_SCALE if scale is None else scale) * max(float(np.std(y)), sigma)
    ridge = np.full(len(names), 1.0 / tau**2)
    ridge[-1] = 0.0
    information = (n_eff / e.size) * (z.T @ z) / sigma**2 + np.diag(ridge)
    covariance = np.linalg.pinv(information, hermitian=True)
    units = np.append(sd, 1.0)
    covariance = covariance / np.outer(units, units)
    covariance = 0.5 * (covariance + covariance.T)
    peak = float(np.max(np.abs(c.sum(axis=1))))
    gains = calibration_prior(names, c, e).covariance * np.outer(shape.units, shape.units)
    return Prior(
        names,
        covariance,
        sigma,
        int(e.size),
        float(n_eff),
        peak,
        coefficients=k,
        gains_covariance=0.5 * (gains + gains.T),
        transient_um2=() if sample_time_s is None else transient_variances(e, sample_time_s),
    )


#: The probe intervals :func:`transient_variances` reports, s (15 min to a day).
TRANSIENT_INTERVALS_S = (900.0, 1800.0, 3600.0, 7200.0, 14400.0, 28800.0, 86400.0)


def transient_variances(
    residue_um: np.ndarray, sample_time_s: float
) -> tuple[tuple[float, float], ...]:
    """Per probe interval ``T`` (:data:`TRANSIENT_INTERVALS_S`), the residue's variance that does
    not persist over it: ``C(0) - mean(C(tau), 0 < tau <= T)`` (um^2, at least 0), ``C`` the
    residue's autocovariance.

    A probe measures the model's error at one instant. Of that error, the
    part that persists (a slow drift the calibration did not capture) is what
    the update should learn; the part that comes and goes within the
    interval (a door, a chiller's cycle, coolant switched on and off) is gone
    before the next probe, and an update that learns it moves the model the
    wrong way half the time. The calibration's residue says how large that
    part is: with the error split as slow + transient, ``C(0)`` is both
    variances and the mean of ``C`` over the interval is the slow part's.
    Intervals shorter than two samples, or not shorter than half the residue
    (whose autocovariance is no longer estimated from enough pairs), are left
    out.
    """
    e = np.asarray(residue_um, dtype=float).ravel()
    e = e - e.mean()
    n = e.size
    size = 1 << int(2 * n - 1).bit_length()
    spectrum = np.fft.rfft(e, size)
    acf = np.fft.irfft(spectrum * np.conj(spectrum), size)[:n] / n
    pairs = []
    for interval_s in TRANSIENT_INTERVALS_S:
        lags = int(interval_s // sample_time_s)
        if lags < 2 or lags >= n // 2:
            continue
        pairs.append((interval_s, max(0.0, float(acf[0] - acf[1 : lags + 1].mean()))))
    return tuple(pairs)


def effective_samples(residue: np.ndarray, window_c: float = 5.0) -> float:
    """The effective sample size ``n / tau`` of an autocorrelated series.

    ``tau = 1 + 2 sum_{k=1}^{M} rho_k``, the integrated autocorrelation time,
    summed up to Sokal's automatic window: the smallest ``M >= window_c * tau(M)``
    (Sokal 1997, "Monte Carlo methods in statistical mechanics", sec. 3).
    Between 1 and ``n``.
    """
    e = np.asarray(residue, dtype=float).ravel()
    n = e.size
    e = e - e.mean()
    size = 1 << int(2 * n - 1).bit_length()
    spectrum = np.fft.rfft(e, size)
    acf = np.fft.irfft(spectrum * np.conj(spectrum), size)[:n]
    if acf[0] <= 0.0:
        return float(n)
    rho = acf / acf[0]
    taus = 1.0 + 2.0 * np.cumsum(rho[1:])
    window = np.flatnonzero(np.arange(1, n) >= window_c * taus)
    tau = float(taus[window[0]]) if window.size else float(taus[-1])
    return float(np.clip(n / max(tau, 1.0), 1.0, n))
