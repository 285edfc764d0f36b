"""How much of a residue one signal's first-order lags explain, scored by blocked cross-validation.

The fitting behind :func:`compd.model.diagnose.diagnose_residue`, for one
candidate signal. For a candidate ``u`` (taken as a change from its first
value, ``u - u(0)``) the residue ``e`` (um) is regressed on first-order zero-order-hold lags of
``u``::

    x_tau(k) = p x_tau(k-1) + (1 - p) u(k-1),   p = exp(-Ts / tau),  x_tau(0) = 0
    e(k) ≈ c + K x_tau(k)                        (one lag)
    e(k) ≈ c + K1 x_tau1(k) + K2 x_tau2(k)        (two lags: heating minus a slower sink)

for a bank of time constants ``tau`` log-spaced from 1 min to 8 h (within
the record). Each lag has unit static gain, so the static gain of the fitted
TF is ``K`` (or ``K1 + K2``) in um per unit of ``u``. The offset ``c`` is
fitted too but belongs to no candidate. Given the filtered regressors the
model is linear and static, so blocked k-fold cross-validation (contiguous
blocks, default 5) is exact and costs only per-block Gram matrices:
``G_b = Z_b^T Z_b`` with ``Z = [1, x_tau..., e]``; a fold is fitted on
``G - G_b`` and scored on ``G_b``. The lag filters run over the whole record
(the inputs are exogenous and known everywhere); only the residue is held out.

The score is the cross-validated explained share of the residue RMS::

    explained % = 100 (1 - sqrt(Σ_blocks Σ (e - ê_heldout)^2 / Σ (e - mean(e))^2))

(the residue's mean is an offset, not an effect). The two-lag form is kept
only if it adds at least ``pair_margin_percent`` points on held-out data.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import scipy.signal
from numpy.typing import NDArray

Array = NDArray[np.float64]

MIN_TIME_CONSTANT_S = 60.0
MAX_TIME_CONSTANT_S = 8 * 3600.0
N_TIME_CONSTANTS = 16


def time_constant_bank(
    sample_time_s: float,
    duration_s: float,
    *,
    min_s: float = MIN_TIME_CONSTANT_S,
    max_s: float = MAX_TIME_CONSTANT_S,
    count: int = N_TIME_CONSTANTS,
) -> Array:
    """Log-spaced time constants in s, kept within ``[2 Ts, duration / 2]`` (at least two)."""
    low = max(min_s, 2.0 * sample_time_s)
    high = max(min(max_s, duration_s / 2.0), 2.0 * low)
    return np.geomspace(low, high, count)


def lag_bank(u: Array, time_constants_s: Array, sample_time_s: float) -> Array:
    """``(n_tau, N)``: ``x_tau`` of the module docstring for each ``tau``, from rest."""
    out = np.empty((len(time_constants_s), len(u)))
    for i, tau in enumerate(time_constants_s):
        pole = float(np.exp(-sample_time_s / tau))
        out[i] = scipy.signal.lfilter([0.0, 1.0 - pole], [1.0, -pole], u)
    return out


@dataclass(frozen=True)
class LagFit:
    """A one- or two-lag model of a residue: its cross-validated explained share, lags and weights."""

    explained_percent: float
    time_constants_s: tuple[float, ...]
    weights: tuple[float, ...]  # K per lag, in um per unit of the scaled signal


def _block_grams(regressors: Array, residue: Array, folds: int) -> Array:
    """``(folds, p, p)`` Gram matrices of ``Z = [1, regressors..., residue]`` per contiguous block."""
    z = np.column_stack([np.ones(len(residue)), regressors.T, residue])
    edges = np.linspace(0, len(residue), folds + 1).astype(int)
    return np.stack([_gram(z[a:b]) for a, b in itertools.pairwise(edges)])


def _gram(z: Array, rows: int = 256) -> Array:
    """``z^T z`` as a sum of products of at most ``rows`` rows.

    Each product stays below OpenBLAS's threading threshold (m n k < 2^18):
    threads on matrices this thin cost more than they save, 7x on a busy
    2-core machine.
    """
    full = (len(z) // rows) * rows
    stacked = z[:full].reshape(-1, rows, z.shape[1])
    rest = z[full:]
    gram: Array = np.matmul(stacked.transpose(0, 2, 1), stacked).sum(axis=0) + rest.T @ rest
    return gram


def _cv_sse(grams: Array, columns: Array) -> tuple[Array, Array]:
    """Held-out SSE summed over folds, and the all-data weights, for models on ``columns``.

    ``columns``: ``(n_models, q)`` indices into the Gram matrix (0 = offset);
    the residue is the last row/column.
    """
    y = grams.shape[1] - 1
    total = grams.sum(axis=0)
    a_all = total[columns[:, :, None], columns[:, None, :]]  # (m, q, q)
    b_all = total[columns, y]  # (m, q)
    sse = np.zeros(len(columns))
    for gram in grams:
        a = a_all - gram[columns[:, :, None], columns[:, None, :]]
        b = b_all - gram[columns, y]
        beta = _solve(a, b)
        held_a = gram[columns[:, :, None], columns[:, None, :]]
        held_b = gram[columns, y]
        sse += (
            gram[y, y]
            - 2.0 * np.einsum("mq,mq->m", beta, held_b)
            + np.einsum("mq,mqr,mr->m", beta, held_a, beta)
        )
    return sse, _solve(a_all, b_all)


def _solve(a: Array, b: Array) -> Array:
    """Stacked least-squares normal equations with a tiny ridge against near-equal lags."""
    scale = np.einsum("mii->mi", a).mean(axis=1)
    ridge = 1e-9 * scale[:, None, None] * np.eye(a.shape[1])
    result: Array = np.linalg.solve(a + ridge, b[:, :, None])[:, :, 0]
    return result


def fit_candidate(
    residue_um: Array,
    u: Array,
    time_constants_s: Array,
    sample_time_s: float,
    *,
    folds: int = 5,
    pair_margin_percent: float = 2.0,
    refine: bool = True,
    first_sample: int = 0,
) -> LagFit:
    """Best one- or two-lag model of the residue from ``u`` by blocked cross-validation.

    The lags are filtered from sample 0; only samples from ``first_sample`` on
    are fitted and scored (a later part of a record, its filters warm).

    With ``refine`` the one-lag time constant is searched again on a grid 8
    times finer between the bank's neighbours of the best one (steps of
    about 5 % in ``tau`` for the default bank) before the two-lag models are
    compared with it.
    """
    residue_um = residue_um[first_sample:]
    bank = lag_bank(u, time_constants_s, sample_time_s)[:, first_sample:]
    single, pair = _best_of_bank(residue_um, bank, time_constants_s, folds)
    if refine:
        logs = np.log(time_constants_s)
        j = int(np.argmin(np.abs(logs - np.log(single.time_constants_s[0]))))
        low, high = logs[max(j - 1, 0)], logs[min(j + 1, len(logs) - 1)]
        finer_taus = np.exp(np.linspace(low, high, 17))
        finer_bank = lag_bank(u, finer_taus, sample_time_s)[:, first_sample:]
        finer, _ = _best_of_bank(residue_um, finer_bank, finer_taus, folds, pairs=False)
        if finer.explained_percent > single.explained_percent:
            single = finer
    if pair is not None and pair.explained_percent > single.explained_percent + pair_margin_percent:
        return pair
    return single


def _best_of_bank(
    residue_um: Array, bank: Array, taus: Array, folds: int, *, pairs: bool = True
) -> tuple[LagFit, LagFit | None]:
    """The best one-lag and the best two-lag model on the lags in ``bank``."""
    n = len(residue_um)
    grams = _block_grams(bank, residue_um, folds)
    sse, weights = _cv_sse(grams, np.array([[0, j + 1] for j in range(len(taus))]))
    j = int(np.argmin(sse))
    single = LagFit(_explained(sse[j], grams, n), (float(taus[j]),), (float(weights[j, 1]),))
    if not pairs or len(taus) < 2:
        return single, None
    models = np.array(
        [[0, j + 1, k + 1] for j in range(len(taus)) for k in range(j + 1, len(taus))]
    )
    sse, weights = _cv_sse(grams, models)
    i = int(np.argmin(sse))
    pair = LagFit(
        _explained(sse[i], grams, n),
        tuple(float(taus[c - 1]) for c in models[i, 1:]),
        tuple(float(w) for w in weights[i, 1:]),
    )
    return single, pair


def _explained(sse: float, grams: Array, n: int) -> float:
    """``100 (1 - sqrt(SSE / Σ (e - mean e)^2))`` from the held-out SSE and the block Grams."""
    total = grams.sum(axis=0)
    spread = total[-1, -1] - total[0, -1] ** 2 / n
    return 100.0 * (1.0 - float(np.sqrt(max(float(sse), 0.0) / spread)))
