"""The prior of the probe update (:mod:`compd.model.probeupdate`): the calibration's posterior, or a default.

"The calibration's posterior as prior" (issue 35 item 2): at fit time the
calibration output is regressed on the model's contributions, and the
parameters' covariance is that regression's ridge posterior widened by the
residue's autocorrelation (its effective sample size, Sokal's integrated
autocorrelation time). A model file without it gets a documented
conservative default. numpy only.
"""

from __future__ import annotations

from dataclasses import dataclass
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


@dataclass(frozen=True, eq=False)
class Prior:
    """The parameters' prior: mean ``(1 .. 1, 0)``, ``covariance`` (p, p) in gain^2 and um^2.

    ``names``: each gain's sub-model, then :data:`BIAS`; ``residue_sigma_um``:
    the calibration residue's standard deviation; ``samples`` and
    ``effective_samples``: the calibration's length and its effective sample
    size (0 for a default prior); ``output_peak_um``: the largest
    ``|output|`` the calibration model gave over its calibration (0:
    unknown); ``source``: ``"calibration"`` (``compd fit`` stored it) or
    ``"default"`` (:func:`default_prior`).
    """

    names: tuple[str, ...]
    covariance: np.ndarray
    residue_sigma_um: float
    samples: int = 0
    effective_samples: float = 0.0
    output_peak_um: float = 0.0
    source: Literal["calibration", "default"] = "calibration"

    def __post_init__(self) -> None:
        p = len(self.names)
        if self.covariance.shape != (p, p):
            raise ModelError(f"prior covariance must be {p} x {p}, is {self.covariance.shape}")
        if not np.all(np.isfinite(self.covariance)):
            raise ModelError("prior covariance must be finite")

    @property
    def mean(self) -> np.ndarray:
        theta = np.ones(len(self.names))
        theta[-1] = 0.0
        return theta


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
