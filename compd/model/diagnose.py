"""Which physical effect is missing from a model: rank candidate signals by how much residue they explain.

Horejs 2015 (sect. 4.3) finds the missing cutting-process effect by fitting a TF
from spindle power to the residue of the air-cutting model. This module does
that for every candidate signal at once and scores each on data it was not
fitted on, so a slow signal that merely shares a trend with the residue does
not win by over-fitting.

Per candidate ``u`` (taken as a change from its first value) the residue is
regressed on one or two first-order lags of ``u`` from a bank of time
constants (1 min to 8 h), scored by blocked k-fold cross-validation as the
explained share of the residue RMS (:mod:`compd.model.lagscore` gives the
equations and the exact per-block Gram-matrix form)::

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

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np
from numpy.typing import NDArray

from compd.model.correlation import Correlations, correlate, whiteness_exceedances
from compd.model.crossval import MIN_FOLD_SAMPLES
from compd.model.lagscore import fit_candidate, time_constant_bank

Array = NDArray[np.float64]

MAX_LAG_S = 7200.0
#: Fewest contiguous blocks a residue is cross-validated on. A short record (a 6 h warm-up run
#: at 5 min is 72 samples) is cut into fewer blocks than asked, never fewer than this.
MIN_BLOCKS = 3
#: Fewest samples diagnosed. Three blocks of ``MIN_FOLD_SAMPLES`` would be 60, but on 60-63
#: samples a residue of noise (AR(1), random-walk candidates) is named an effect 30-37 % of the
#: time; from 64 on 14-27 %, as at the 100 samples of five blocks (27 %).
MIN_DIAGNOSED_SAMPLES = 64
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


def diagnosis_blocks(n_samples: int, wanted: int = 5) -> int:
    """How many contiguous blocks (up to ``wanted``) a residue of ``n_samples`` is diagnosed on.

    Each block holds at least ``MIN_FOLD_SAMPLES`` samples, and there are at
    least :data:`MIN_BLOCKS`; fewer than :data:`MIN_DIAGNOSED_SAMPLES` samples
    is a ValueError saying how many are needed.
    """
    if n_samples < MIN_DIAGNOSED_SAMPLES:
        raise ValueError(
            f"{n_samples} samples are too few to cross-validate: at least "
            f"{MIN_DIAGNOSED_SAMPLES} are needed ({MIN_BLOCKS} blocks of {MIN_FOLD_SAMPLES} or more)"
        )
    return max(MIN_BLOCKS, min(wanted, n_samples // MIN_FOLD_SAMPLES))


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
        ``measured - predicted`` (Horejs 2015 eq. 3), um, one value per sample.
    candidates
        Signal name -> values (any unit), as long as the residue. Each is
        used as a change from its first value. A constant one is an error:
        it cannot explain anything, so the caller should leave it out.
    sample_time_s
        Sample time of both, s.
    folds
        Contiguous cross-validation blocks (at least 20 samples each; fewer on
        a short record, :func:`diagnosis_blocks`).
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
    folds = diagnosis_blocks(n, folds)
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
