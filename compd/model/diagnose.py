"""Which physical effect is missing from a model: rank candidate signals by how much residue they explain.

Seed 001 (sect. 4.3) finds the missing cutting-process effect by fitting a TF
from spindle power to the residue of the air-cutting model. This module does
that for every candidate signal at once and scores each on data it was not
fitted on, so a slow signal that merely shares a trend with the residue does
not win by over-fitting.

Per candidate ``u`` (taken as a change from its first value, ``u - u(0)``)
the residue ``e`` (um) is regressed on first-order zero-order-hold lags of
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

Blocked cross-validation does not fully protect against chance: two smooth
signals that have nothing to do with each other can still share slow
wiggles across blocks. Each candidate is therefore also scored shifted
circularly by a third, a half and two thirds of the record (same spectrum,
same amplitudes, no causal alignment with the residue); the best of those is its
``chance_percent``, and a candidate is named as the missing effect only if
it explains ``min_explained_percent`` points more than that.
Corroborating evidence is the residue/input cross-correlation test with
Bartlett bounds (:mod:`compd.model.correlation`); the residue is called white
when its autocorrelation stays inside its 99 % bounds.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np
import scipy.signal
from numpy.typing import NDArray

from compd.model.correlation import Correlations, correlate, whiteness_exceedances

Array = NDArray[np.float64]

MIN_TIME_CONSTANT_S = 60.0
MAX_TIME_CONSTANT_S = 8 * 3600.0
N_TIME_CONSTANTS = 16
MAX_LAG_S = 7200.0
MIN_EXPLAINED_PERCENT = 10.0
"""Below this cross-validated share no candidate is named as the missing effect."""


@dataclass(frozen=True)
class CandidateScore:
    """How much of the residue one candidate signal explains, and the evidence for it."""

    signal: str
    explained_percent: float
    """Cross-validated: ``100 (1 - RMS(residue - predicted) / RMS(residue))`` on held-out blocks."""
    time_constant_s: float
    """Of the fitted lag (two lags: the one with the larger weight ``|K_i|``)."""
    gain_um_per_unit: float
    """Static gain of the fitted TF, sign included, um per unit of the signal."""
    sign: int
    """+1 / -1: direction of the effect (of the dominant lag when the static gain is ~0)."""
    lag_s: float
    """Lag of the largest residue/input cross-correlation (input leading)."""
    xcorr_peak: float
    """That normalised cross-correlation, signed."""
    xcorr_bound: float
    """Its 99 % Bartlett bound."""
    significant: bool
    """``|xcorr_peak| > xcorr_bound``."""
    time_constants_s: tuple[float, ...] = ()
    """Every fitted lag's time constant (one or two)."""
    gains_um_per_unit: tuple[float, ...] = ()
    """Every fitted lag's static gain, in the order of ``time_constants_s``."""
    chance_percent: float = float("nan")
    """Explained share reached by the same signal shifted in time (see :func:`diagnose_residue`): chance level."""

    @property
    def excess_percent(self) -> float:
        """``explained_percent`` above the chance level (chance counted from 0 %)."""
        return self.explained_percent - max(self.chance_percent, 0.0)


@dataclass(frozen=True, eq=False)  # eq=False: arrays have no single truth value
class Diagnosis:
    """Candidates ranked by explained residue, the residue's whiteness, and the correlations behind them."""

    candidates: tuple[CandidateScore, ...]
    """Best first (highest cross-validated explained share)."""
    residue_white: bool
    """The residue autocorrelation is inside its 99 % bounds (up to the chance allowance)."""
    sample_time_s: float
    residue_rms_um: float
    """RMS of the residue about its mean: the denominator of every explained share."""
    min_explained_percent: float
    lags_s: Array
    """Lags of the correlation arrays, ``0..max_lag`` samples, in s."""
    autocorrelation: Array
    autocorrelation_bound: Array
    naive_bound: float
    """``2.576 / sqrt(N)``, for comparison with the Bartlett bounds."""
    cross_correlation: Mapping[str, Array] = field(default_factory=dict)
    """Per candidate: residue/input cross-correlation over ``lags_s``."""
    whiteness_outside: int = 0
    """Lags whose autocorrelation leaves its bound."""
    whiteness_allowed: int = 0
    """How many may by chance for a white residue (99 % binomial quantile)."""

    @property
    def missing_effect(self) -> CandidateScore | None:
        """The best-ranked candidate that explains at least ``min_explained_percent`` beyond chance.

        ``None`` when the residue is white or no candidate does.
        """
        if self.residue_white:
            return None
        return next(
            (c for c in self.candidates if c.excess_percent >= self.min_explained_percent), None
        )


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
class _Fit:
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
) -> _Fit:
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
) -> tuple[_Fit, _Fit | None]:
    """The best one-lag and the best two-lag model on the lags in ``bank``."""
    n = len(residue_um)
    grams = _block_grams(bank, residue_um, folds)
    sse, weights = _cv_sse(grams, np.array([[0, j + 1] for j in range(len(taus))]))
    j = int(np.argmin(sse))
    single = _Fit(_explained(sse[j], grams, n), (float(taus[j]),), (float(weights[j, 1]),))
    if not pairs or len(taus) < 2:
        return single, None
    models = np.array(
        [[0, j + 1, k + 1] for j in range(len(taus)) for k in range(j + 1, len(taus))]
    )
    sse, weights = _cv_sse(grams, models)
    i = int(np.argmin(sse))
    pair = _Fit(
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


def diagnose_residue(
    residue_um: Array,
    candidates: Mapping[str, Array],
    sample_time_s: float,
    *,
    folds: int = 5,
    max_lag_s: float = MAX_LAG_S,
    time_constants_s: Array | None = None,
    pair_margin_percent: float = 2.0,
    min_explained_percent: float = MIN_EXPLAINED_PERCENT,
    first_sample: int = 0,
) -> Diagnosis:
    """Rank ``candidates`` by how much of ``residue_um`` each explains on held-out data.

    Parameters
    ----------
    residue_um
        ``measured - predicted`` (seed 001 eq. 3), um, one value per sample.
    candidates
        Signal name -> values (any unit), as long as the residue. Each is
        used as a change from its first value. A constant one is an error:
        it cannot explain anything, so the caller should leave it out.
    sample_time_s
        Sample time of both, s.
    folds
        Contiguous cross-validation blocks (at least 20 samples each).
    max_lag_s
        Largest correlation lag and the Bartlett lag window, s (clipped to a
        quarter of the record).
    time_constants_s
        The lag bank (default :func:`time_constant_bank`: 16 from 1 min to 8 h).
    pair_margin_percent
        Points the two-lag model must add on held-out data to be kept.
    min_explained_percent
        Points above chance a candidate must explain to be named
        (:attr:`Diagnosis.missing_effect`).
    first_sample
        Only the residue from this sample on is diagnosed; the candidates'
        changes and lags still start at sample 0 (a later part of a record).
    """
    whole = np.asarray(residue_um, dtype=float)
    e = whole[first_sample:]
    n = len(e)
    if n < 20 * folds:
        raise ValueError(f"{n} samples are too few to cross-validate on {folds} blocks")
    names = list(candidates)
    raw = np.array([np.asarray(candidates[name], dtype=float) for name in names]).reshape(
        len(names), len(whole)
    )
    change = raw - raw[:, :1]
    spread = change.std(axis=1)
    constant = [name for name, s in zip(names, spread, strict=True) if s == 0.0]
    if constant:
        raise ValueError(f"constant candidate signal(s) {constant} explain nothing")
    taus = (
        time_constant_bank(sample_time_s, n * sample_time_s)
        if time_constants_s is None
        else np.asarray(time_constants_s, dtype=float)
    )
    max_lag = int(min(max(1, round(max_lag_s / sample_time_s)), max(1, n // 4)))
    corr: Correlations = correlate(e, change[:, first_sample:], max_lag)
    outside, allowed = whiteness_exceedances(corr)

    scores = []
    for i, name in enumerate(names):
        scaled = change[i] / spread[i]  # unit spread: a well-conditioned regression
        fit = fit_candidate(
            whole,
            scaled,
            taus,
            sample_time_s,
            folds=folds,
            pair_margin_percent=pair_margin_percent,
            first_sample=first_sample,
        )
        chance = max(
            fit_candidate(
                whole,
                np.roll(scaled, shift),
                taus,
                sample_time_s,
                folds=folds,
                pair_margin_percent=pair_margin_percent,
                refine=False,
                first_sample=first_sample,
            ).explained_percent
            for shift in (n // 3, n // 2, (2 * n) // 3)
        )
        gains = tuple(w / float(spread[i]) for w in fit.weights)
        tau_fit = fit.time_constants_s
        dominant = int(np.argmax(np.abs(fit.weights)))
        static = float(sum(gains))
        sign_source = static if abs(static) > 1e-3 * max(abs(g) for g in gains) else gains[dominant]
        k = int(np.argmax(np.abs(corr.cross[i])))
        peak = float(corr.cross[i, k])
        bound = float(corr.cross_bound[i])
        scores.append(
            CandidateScore(
                signal=name,
                explained_percent=fit.explained_percent,
                time_constant_s=tau_fit[dominant],
                gain_um_per_unit=static,
                sign=1 if sign_source >= 0.0 else -1,
                lag_s=k * sample_time_s,
                xcorr_peak=peak,
                xcorr_bound=bound,
                significant=bool(abs(peak) > bound),
                time_constants_s=tau_fit,
                gains_um_per_unit=gains,
                chance_percent=chance,
            )
        )
    scores.sort(key=lambda s: -s.explained_percent)
    return Diagnosis(
        candidates=tuple(scores),
        residue_white=outside <= allowed,
        sample_time_s=sample_time_s,
        residue_rms_um=float(np.std(e)),
        min_explained_percent=min_explained_percent,
        lags_s=np.arange(max_lag + 1, dtype=np.float64) * float(sample_time_s),
        autocorrelation=corr.autocorrelation,
        autocorrelation_bound=corr.autocorrelation_bound,
        naive_bound=corr.naive_bound,
        cross_correlation=MappingProxyType({name: corr.cross[i] for i, name in enumerate(names)}),
        whiteness_outside=outside,
        whiteness_allowed=allowed,
    )
