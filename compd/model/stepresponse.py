"""Step responses, static gains and their standard errors of a model's inputs (what MATLAB's ``step`` shows).

A compensation output is a sum of sub-models, each a gained TF of one input
(a lag bank gives one input four or five of them). What a user checks is per
input: how many um the output moves per unit step of it, how fast, and how
sure the gain is. The functions here are pure numpy/scipy on discrete TFs.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.signal import lfilter

from compd.model.transfer import DiscreteTF

Array = NDArray[np.float64]

#: The step is drawn over this many of the slowest time constant: the rest is e^-8 < 0.05 %.
SETTLING_TIME_CONSTANTS = 8.0
#: The shortest horizon drawn (a static gain's step is flat: show it over an hour).
MIN_HORIZON_S = 3600.0
#: At most this many samples per step response (a very slow pole is drawn coarser, not longer).
MAX_STEP_SAMPLES = 200_000


def static_gain(tfs: Sequence[DiscreteTF], gains: Sequence[float]) -> float:
    """``sum gain_i * B_i(1) / A_i(1)``: the output's final change per unit step of the input."""
    return float(sum(g * tf.static_gain() for tf, g in zip(tfs, gains, strict=True)))


def slowest_time_constant_s(tfs: Sequence[DiscreteTF], sample_time_s: float) -> float:
    """The largest time constant of any real stable pole, in s (0 for static TFs)."""
    taus = [float(t) for tf in tfs for t in tf.time_constants_s(sample_time_s)]
    finite = [t for t in taus if np.isfinite(t) and t > 0.0]
    return max(finite, default=0.0)


def dominant_time_constants_s(
    tfs: Sequence[DiscreteTF], gains: Sequence[float], sample_time_s: float, count: int = 2
) -> tuple[float, ...]:
    """Time constants (s) of the ``count`` dynamic sub-models with the largest ``|gain * B(1)/A(1)|``."""
    weighted = []
    for tf, g in zip(tfs, gains, strict=True):
        taus = [float(t) for t in tf.time_constants_s(sample_time_s) if np.isfinite(t) and t > 0]
        if taus:
            weighted.append((abs(g * tf.static_gain()), max(taus)))
    weighted.sort(reverse=True)
    return tuple(tau for _, tau in weighted[:count])


def step_response(
    tfs: Sequence[DiscreteTF], gains: Sequence[float], sample_time_s: float
) -> tuple[Array, Array]:
    """Times (s) and the summed response (output units per unit) to a unit step of the input at 0.

    Long enough to settle (:data:`SETTLING_TIME_CONSTANTS` of the slowest
    pole, at least :data:`MIN_HORIZON_S`), so its last value is
    :func:`static_gain` to within e^-8.
    """
    slowest = slowest_time_constant_s(tfs, sample_time_s)
    delay = max((tf.nk for tf in tfs), default=0)
    horizon_s = max(SETTLING_TIME_CONSTANTS * slowest, MIN_HORIZON_S)
    samples = int(np.ceil(horizon_s / sample_time_s)) + delay + 2
    step = 1
    if samples > MAX_STEP_SAMPLES:  # subsample the drawn points, not the simulation
        step = int(np.ceil(samples / MAX_STEP_SAMPLES))
    u = np.ones(samples)
    y = np.zeros(samples)
    for tf, g in zip(tfs, gains, strict=True):
        y += g * lfilter(tf.b, tf.a, np.concatenate([np.zeros(tf.nk), u])[:samples])
    index = np.arange(0, samples, step)
    if index[-1] != samples - 1:
        index = np.append(index, samples - 1)
    time_s = np.asarray(index * sample_time_s, dtype=np.float64)
    return time_s, y[index]


@dataclass(frozen=True)
class GainCheck:
    """How one record judges a model's gains: the regression of the measured output on the contributions.

    ``factors``: the scale on each contribution the record fits best (1: the
    record agrees with the model's gain); ``relative_errors``: one standard
    error of each factor (NaN: a zero or collinear contribution);
    ``residue_rms``: what the regression leaves, in the output's unit;
    ``lag1_autocorrelation``: of that residue; ``widening``: the factor
    ``sqrt((1 + rho) / (1 - rho))`` the white-noise errors were widened by.
    A residue that is an effect the model lacks (a slow drift, rho near 1)
    is not noise: the errors then say how little this record pins the gains,
    and they grow with it, whatever the gains' calibration.
    """

    factors: Array
    relative_errors: Array
    residue_rms: float
    lag1_autocorrelation: float
    widening: float


def gain_check(contributions: Array, measured: Array) -> GainCheck:
    """Scale factors on each column of ``contributions`` (N, G) that ``measured`` fits, with their errors.

    Regresses ``measured`` on the columns and a constant; at the model the
    factors are 1, so ``K_j * se_j`` is the standard error of input ``j``'s
    static gain with its dynamics held fixed. The ordinary least-squares
    covariance ``s^2 (C'C)^-1`` assumes a white residue; it is widened by
    ``sqrt((1 + rho) / (1 - rho))`` for the residue's lag-1 autocorrelation
    ``rho`` (an AR(1) residue, rho at most 0.999), so slow thermal residues
    are not overconfident.
    """
    c = np.asarray(contributions, dtype=float)
    y = np.asarray(measured, dtype=float)
    design = np.column_stack([c, np.ones(len(y))])
    keep = np.all(np.isfinite(design), axis=1) & np.isfinite(y)
    design, y = design[keep], y[keep]
    nothing = np.full(c.shape[1], np.nan)
    dof = len(y) - design.shape[1]
    if dof < 2:
        return GainCheck(nothing, nothing.copy(), np.nan, np.nan, np.nan)
    theta, *_ = np.linalg.lstsq(design, y, rcond=None)
    residue = y - design @ theta
    rms = float(np.sqrt(np.mean(residue**2)))
    centred = residue - residue.mean()
    denominator = float(centred @ centred)
    rho = float(centred[1:] @ centred[:-1]) / denominator if denominator > 0 else 0.0
    widening = float(np.sqrt((1.0 + min(max(rho, 0.0), 0.999)) / (1.0 - min(max(rho, 0.0), 0.999))))
    gram = design.T @ design
    factors = theta[:-1].copy()
    if np.linalg.cond(gram) > 1e12:
        return GainCheck(factors, nothing, rms, rho, widening)
    variance = float(residue @ residue) / dof
    se = np.sqrt(np.clip(np.diag(np.linalg.inv(gram)) * variance, 0.0, None)) * widening
    out = se[:-1].copy()
    out[~np.any(c[keep] != 0.0, axis=0)] = np.nan
    return GainCheck(factors, out, rms, rho, widening)


def gain_standard_errors(contributions: Array, measured: Array) -> Array:
    """Relative standard errors of scale factors on each column of ``contributions`` (N, G).

    :func:`gain_check`'s ``relative_errors``: NaN where a column is zero or
    collinear with the others.
    """
    return gain_check(contributions, measured).relative_errors
