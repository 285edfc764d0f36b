"""Position-dependent feed-axis errors (Pahk 2002 eq. 5): slope channels for identification.

Pahk 2002 models a feed axis's thermal error at position ``P`` (mm) as::

    Error(P, T) = Error_g(P) + m1(T) * P + m2(T)

``Error_g`` is geometric (cold) and drops out of changes from start; the
offset ``m2`` is what every compd model already is, a sum of TFs of the
inputs; the slope ``m1`` (um per mm) is a second sum of TFs, whose output
compd multiplies by ``P - P_ref`` (:class:`compd.model.structure.Position`).

Identification runs in two steps, so neither ARX nor OE has to learn a
product of a filtered signal and the position (not linear in their
parameters):

1. :func:`scaled_inputs` makes each slope channel an ordinary input,
   ``u_i(k) * (P(k) - P_ref)``, exactly as a phase gate multiplies an input
   by its mask; ARX, OE or MLR fit denominators and numerators as usual.
   This puts the position *before* the TF, which is right only while the
   axis rests at one position for many time constants.
2. :func:`refit_numerators` keeps those denominators and re-estimates every
   numerator by least squares with the position *after* the TF, the form
   the model file runs::

       y(k) = sum_i s_i(k) * sum_j b_ij * x_ij(k),
       x_ij = q^-(nk_i + j) / F_i(q^-1) * u_i,   s_i = P - P_ref (slope) or 1 (offset)

   which is linear in ``b`` and minimises the free-run simulation error over
   the numerators exactly (so it is never worse than step 1's numerators).
3. :func:`refine_scaled` then moves numerators and denominators together
   down the gradient of that same free-run error (Gauss-Newton in a trust
   region, analytic Jacobian), because step 1's poles are biased whenever
   the axis moves within a time constant. It is kept only if the result is
   stable and simulates the record better.

On the twin's ``feed_positions`` run (X moves every 2-15 min, screw time
constant ~14 min) step 3 takes a feed-rate slope model from 70 % to 94 %
fit on an unseen run; with a screw-temperature input (nearly static) it
changes little.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import scipy.optimize
import scipy.signal

from compd.errors import ModelError
from compd.model.transfer import DiscreteTF

#: Fewest distinct positions a slope can be identified from (a line needs two points).
MIN_POSITIONS = 2


def check_position(position_mm: np.ndarray, n: int) -> np.ndarray:
    """``position - reference`` (mm) as floats, refused unless finite and at >= 2 distinct values."""
    p = np.asarray(position_mm, dtype=float)
    if p.shape != (n,):
        raise ModelError(f"position has shape {p.shape}, the output has ({n},)")
    if not np.all(np.isfinite(p)):
        raise ModelError("the position signal contains NaN or inf")
    distinct = np.unique(p).size
    if distinct < MIN_POSITIONS:
        raise ModelError(
            f"the position signal takes {distinct} distinct value(s) in this record, so the "
            "slope (um per mm) cannot be told from the offset; measure at two or more positions "
            "along the axis, or fit without a position"
        )
    return p


def channel_scales(scaled: Sequence[bool], position_mm: np.ndarray) -> np.ndarray:
    """(n, n_channels): ``P - P_ref`` for slope channels, 1 for offset channels."""
    scales = np.ones((position_mm.size, len(scaled)))
    scales[:, np.asarray(scaled, dtype=bool)] = position_mm[:, None]
    return scales


def simulate_scaled(
    tfs: Sequence[DiscreteTF], inputs: np.ndarray, scales: np.ndarray
) -> np.ndarray:
    """``sum_i s_i(k) * TF_i(u_i)(k)`` from rest (um): the model as the compiled engine runs it."""
    total = np.zeros(inputs.shape[0])
    for i, tf in enumerate(tfs):
        total += scales[:, i] * scipy.signal.lfilter(tf.b, tf.a, inputs[:, i])
    return total


def refit_numerators(
    y: np.ndarray,
    inputs: np.ndarray,
    tfs: Sequence[DiscreteTF],
    scales: np.ndarray,
    *,
    first_sample: int = 0,
) -> list[DiscreteTF]:
    """Every channel's numerator by least squares with its output scaled (step 2 above).

    ``inputs``: (n, n_channels) *unscaled* inputs ``u_i`` (changes from start);
    ``tfs``: the step-1 TFs, whose denominators and delays are kept;
    ``scales``: :func:`channel_scales`; only samples from ``first_sample`` on
    are fitted (the channels are filtered from sample 0). Returns new TFs,
    one per channel.
    """
    columns: list[np.ndarray] = []
    sizes: list[int] = []
    for i, tf in enumerate(tfs):
        filtered = scipy.signal.lfilter([1.0], tf.den, inputs[:, i])
        taps = len(tf.num)
        for j in range(taps):
            shift = tf.nk + j
            delayed = np.zeros_like(filtered)
            if shift < filtered.size:
                delayed[shift:] = filtered[: filtered.size - shift]
            columns.append(scales[:, i] * delayed)
        sizes.append(taps)
    regressors = np.column_stack(columns)[first_sample:]
    theta = np.linalg.lstsq(regressors, y[first_sample:], rcond=None)[0]
    refitted = []
    start = 0
    for tf, taps in zip(tfs, sizes, strict=True):
        refitted.append(DiscreteTF.from_coefficients(theta[start : start + taps], tf.den, tf.nk))
        start += taps
    return refitted


def _shifted(x: np.ndarray, samples: int) -> np.ndarray:
    """``q^-samples x``: ``x`` delayed by ``samples``, zeros before."""
    out = np.zeros_like(x)
    if samples < x.size:
        out[samples:] = x[: x.size - samples]
    return out


def refine_scaled(
    y: np.ndarray,
    inputs: np.ndarray,
    tfs: Sequence[DiscreteTF],
    scales: np.ndarray,
    *,
    max_evaluations: int = 60,
    first_sample: int = 0,
) -> list[DiscreteTF]:
    """Numerators and denominators together by least squares on the free-run error (step 3 above).

    Minimises ``sum_k (y(k) - sum_i s_i(k) B_i/F_i u_i(k))^2`` from ``tfs``
    (orders and delays kept, ``F_i`` monic) with the analytic Jacobian::

        d/d b_ij = s_i q^-(nk_i + j) / F_i u_i
        d/d f_ij = -s_i q^-j / F_i (B_i/F_i u_i)

    The sum runs over ``k >= first_sample``; the simulation starts at sample 0.
    Returns ``tfs`` unchanged when the optimum found is unstable or no better.
    """
    layout = [(len(tf.num), len(tf.den) - 1, tf.nk) for tf in tfs]
    start = np.concatenate(
        [np.r_[np.asarray(tf.num), np.asarray(tf.den[1:])] / tf.den[0] for tf in tfs]
    )

    def split(theta: np.ndarray) -> list[tuple[np.ndarray, np.ndarray, int]]:
        parts, at = [], 0
        for nb, nf, nk in layout:
            parts.append((theta[at : at + nb], np.r_[1.0, theta[at + nb : at + nb + nf]], nk))
            at += nb + nf
        return parts

    def residual(theta: np.ndarray) -> np.ndarray:
        total = -np.asarray(y, dtype=float)
        for i, (b, f, nk) in enumerate(split(theta)):
            total = total + scales[:, i] * _shifted(scipy.signal.lfilter(b, f, inputs[:, i]), nk)
        return total[first_sample:]

    def jacobian(theta: np.ndarray) -> np.ndarray:
        columns = []
        for i, (b, f, nk) in enumerate(split(theta)):
            filtered = _shifted(scipy.signal.lfilter([1.0], f, inputs[:, i]), nk)
            response = scipy.signal.lfilter(b, [1.0], filtered)  # B/F q^-nk u
            twice = scipy.signal.lfilter([1.0], f, response)
            columns += [scales[:, i] * _shifted(filtered, j) for j in range(b.size)]
            columns += [-scales[:, i] * _shifted(twice, j) for j in range(1, f.size)]
        return np.column_stack(columns)[first_sample:]

    with np.errstate(over="ignore", invalid="ignore"):
        result = scipy.optimize.least_squares(
            residual, start, jac=jacobian, method="trf", x_scale="jac", max_nfev=max_evaluations
        )
    refined = [DiscreteTF.from_coefficients(b, f, nk) for b, f, nk in split(result.x)]
    stable = all(np.all(np.abs(np.roots(tf.den)) < 1.0) for tf in refined if len(tf.den) > 1)
    if not (stable and np.isfinite(result.cost)) or result.cost >= 0.5 * np.sum(
        residual(start) ** 2
    ):
        return list(tfs)
    return refined
