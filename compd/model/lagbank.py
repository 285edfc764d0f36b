"""Regularised lag-bank identification: stable by construction, linear in its parameters.

Each input ``u_i`` (a change from the record's start) drives a bank of
first-order lags at fixed time constants ``tau_j`` (0 meaning the input
itself), and the output is their weighted sum::

    y(k) = sum_i sum_j g_ij * L_j(u_i)(k),    L_j = 1 / (tau_j s + 1)   (zero-order hold)

Every term is a first-order TF with a pole on the positive real axis inside
the unit circle, so the model is stable whatever the weights, and every
weight is a static gain in um per input unit. Fitting it is linear least
squares; no iterate can run away to an eight-year time constant.

Many temperature sensors on one machine move together (one heat source seen
from several places), so the free least-squares weights cancel each other in
huge pairs that fit the calibration and fail on the next run. Two measures
keep them honest, both chosen by leave-one-cycle-out cross-validation
(:mod:`compd.model.crossval`):

- the inputs are first projected on their leading ``m`` principal directions
  over the fitted samples (the temperature field's few independent modes,
  the literature's PCA sensor grouping); the lags run on the modes;
- ridge regularisation on standardised lag features with weight ``lambda``.

The result maps back to plain per-input gains ``g_ij``, which the model file
holds as ordinary first-order sub-models, so the service, ``compare`` and
``simulate`` run it like any other model.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import scipy.signal

from compd.errors import ModelError
from compd.model.crossval import Folds, cross_validated_prediction, pooled_fit_percent
from compd.model.experiments import ONE, each
from compd.model.metrics import fit_percent
from compd.model.transfer import DiscreteTF

#: 0 (the input itself), 5 min, 20 min, 1 h, 3 h: the span of a machine tool's thermal time constants.
DEFAULT_TIME_CONSTANTS_S: tuple[float, ...] = (0.0, 300.0, 1200.0, 3600.0, 10800.0)
#: Ridge weights tried, relative to the number of fitted samples on standardised features.
DEFAULT_RIDGE_WEIGHTS: tuple[float, ...] = tuple(float(w) for w in np.logspace(-5, 0, 11))
#: Among settings whose cross-validated fit is within this many points of the best, the
#: simplest (fewest modes, then the strongest ridge) is kept: selection noise on a few
#: cycles is about this size, and the simpler model travels better.
SELECTION_TOLERANCE_POINTS = 0.5
#: An input may move the output by at most this many times the output's range over the
#: fitted samples (the guard rails' warning level, :mod:`compd.model.guards`).
MAX_REACH_RATIO = 3.0


@dataclass(frozen=True, eq=False)
class LagBankFit:
    """A fitted lag bank: per-input gains at each time constant, and how it was chosen."""

    time_constants_s: tuple[float, ...]
    gains: np.ndarray  # (n_inputs, n_time_constants), um per input unit
    n_modes: int
    ridge_weight: float
    fit_percent: float  # on the fitted samples, model run through the whole record
    cv_fit_percent: float | None  # pooled held-out fit of the chosen setting
    predicted_um: np.ndarray = field(repr=False)  # the model's output over the whole record
    cv_predicted_um: np.ndarray | None = field(repr=False, default=None)

    def channel_tfs(self, sample_time_s: float) -> list[list[DiscreteTF]]:
        """Per input, one discrete TF per time constant (ZOH of ``g / (tau s + 1)``; tau 0: a gain)."""
        return [
            [
                lag_tf(float(g), tau, sample_time_s)
                for g, tau in zip(row, self.time_constants_s, strict=True)
            ]
            for row in self.gains
        ]


#: A lag bank's sub-model names: ``PREFIX_gain`` and ``PREFIX_lag_300s`` (PREFIX: the input,
#: or ``SIGNAL_effect`` for an extension), so readers can group the lags of one input.
_LAG_NAME = re.compile(r"^(?P<prefix>.+)_(?:gain|lag_[0-9.e+]+s)$")


def lag_name(prefix: str, time_constant_s: float) -> str:
    """The sub-model name of the lag at ``time_constant_s`` (0: the gain) of ``prefix``."""
    return f"{prefix}_gain" if time_constant_s == 0.0 else f"{prefix}_lag_{time_constant_s:g}s"


def lag_prefix(name: str) -> str | None:
    """What :func:`lag_name` was given, or None for a name that is not a lag's."""
    match = _LAG_NAME.match(name)
    return None if match is None else match["prefix"]


def lag_tf(gain: float, time_constant_s: float, sample_time_s: float) -> DiscreteTF:
    """``gain / (tau s + 1)`` held by zero-order hold at ``sample_time_s``; ``tau = 0`` is the gain."""
    if time_constant_s == 0.0:
        return DiscreteTF.from_coefficients([gain], [1.0])
    pole = float(np.exp(-sample_time_s / time_constant_s))
    return DiscreteTF.from_coefficients([0.0, gain * (1.0 - pole)], [1.0, -pole])


def lag_features(
    u: np.ndarray,
    time_constants_s: Sequence[float],
    sample_time_s: float,
    starts: Sequence[int] = ONE,
) -> np.ndarray:
    """``(n, p * n_tau)`` columns ``L_j(u_i)``, grouped by time constant (all inputs at tau_0 first).

    Each lag starts from rest at every experiment's start (:mod:`compd.model.experiments`).
    """
    u = np.asarray(u, dtype=float)
    return each(lambda part: _lag_features(part, time_constants_s, sample_time_s), u, starts)


def _lag_features(
    u: np.ndarray, time_constants_s: Sequence[float], sample_time_s: float
) -> np.ndarray:
    columns = []
    for tau in time_constants_s:
        if tau == 0.0:
            columns.append(u)
            continue
        pole = np.exp(-sample_time_s / tau)
        columns.append(scipy.signal.lfilter([0.0, 1.0 - pole], [1.0, -pole], u, axis=0))
    return np.hstack(columns)


def _principal_directions(u: np.ndarray, fitted: np.ndarray) -> np.ndarray:
    """Columns: the inputs' principal directions over the fitted samples, strongest first."""
    block = u[fitted]
    _, _, vt = np.linalg.svd(block - block.mean(axis=0), full_matrices=False)
    return np.asarray(vt.T)


class _Design:
    """Lag features of the inputs' modes over some fitted samples, with their Gram matrix, ready to solve."""

    def __init__(
        self,
        u: np.ndarray,
        y: np.ndarray,
        fitted: np.ndarray,
        time_constants_s: Sequence[float],
        sample_time_s: float,
        starts: Sequence[int] = ONE,
    ) -> None:
        self.directions = _principal_directions(u, fitted)
        self.n_taus = len(time_constants_s)
        self.max_modes = self.directions.shape[1]
        self.starts = tuple(starts)
        features = lag_features(u @ self.directions, time_constants_s, sample_time_s, starts)
        scale = features[fitted].std(axis=0)
        self.scale = np.where(scale > 0.0, scale, 1.0)
        self.features = features / self.scale
        block = self.features[fitted]
        # One Gram matrix for all modes: each setting solves on a sub-block of it.
        self.gram = block.T @ block
        self.rhs = block.T @ y[fitted]
        self.n_fitted = int(fitted.sum())

    def release(self) -> None:
        """Drop the feature matrix (the Gram matrix stays): it is the design's only large part."""
        self.features = np.zeros((0, self.scale.size))

    def restore(
        self, u: np.ndarray, time_constants_s: Sequence[float], sample_time_s: float
    ) -> None:
        """Rebuild the feature matrix dropped by :meth:`release`."""
        features = lag_features(u @ self.directions, time_constants_s, sample_time_s, self.starts)
        self.features = features / self.scale

    def columns(self, n_modes: int) -> np.ndarray:
        """Indices of the feature columns of the leading ``n_modes`` modes, at every time constant."""
        return np.concatenate([np.arange(n_modes) + j * self.max_modes for j in range(self.n_taus)])

    def solve(self, n_modes: int, weights: Sequence[float]) -> list[np.ndarray]:
        """Ridge weights (standardised) for each ridge weight, via one eigendecomposition."""
        cols = self.columns(n_modes)
        eigenvalues, vectors = np.linalg.eigh(self.gram[np.ix_(cols, cols)])
        projected = vectors.T @ self.rhs[cols]
        return [vectors @ (projected / (eigenvalues + w * self.n_fitted)) for w in weights]

    def predict(
        self, n_modes: int, coefficients: np.ndarray, rows: np.ndarray | None = None
    ) -> np.ndarray:
        features = self.features if rows is None else self.features[rows]
        return np.asarray(features[:, self.columns(n_modes)] @ coefficients)

    def gains(self, n_modes: int, coefficients: np.ndarray) -> np.ndarray:
        """Per-input gains ``(p, n_tau)``: the mode weights mapped back through the directions."""
        full = np.zeros(self.max_modes * self.n_taus)
        full[self.columns(n_modes)] = coefficients
        per_mode = (full / self.scale).reshape(self.n_taus, self.max_modes)  # (tau, mode)
        return np.asarray(self.directions @ per_mode.T)  # (input, tau)


def checked_bank_data(
    y: np.ndarray, u: np.ndarray, time_constants_s: Sequence[float]
) -> tuple[np.ndarray, np.ndarray, tuple[float, ...]]:
    """``y``, ``u`` as float arrays and the time constants as a tuple; ModelError says what is wrong."""
    y = np.asarray(y, dtype=float)
    u = np.asarray(u, dtype=float)
    if u.ndim != 2 or u.shape[0] != y.size:
        raise ModelError(f"inputs must be (n_samples, n_inputs) with {y.size} samples")
    if not np.all(np.isfinite(u)) or not np.all(np.isfinite(y)):
        raise ModelError("inputs and output must be finite")
    taus = tuple(float(t) for t in time_constants_s)
    if not taus or any(not np.isfinite(t) or t < 0.0 for t in taus) or len(set(taus)) != len(taus):
        raise ModelError(f"time constants must be distinct and >= 0 s, got {list(taus)}")
    return y, u, taus


def fit_lag_bank(
    y: np.ndarray,
    u: np.ndarray,
    *,
    sample_time_s: float,
    folds: Folds,
    fitted: np.ndarray | None = None,
    time_constants_s: Sequence[float] = DEFAULT_TIME_CONSTANTS_S,
    ridge_weights: Sequence[float] = DEFAULT_RIDGE_WEIGHTS,
    max_modes: int | None = None,
    max_reach_ratio: float = MAX_REACH_RATIO,
    starts: Sequence[int] = ONE,
) -> LagBankFit:
    """Fit ``y`` (um) from the columns of ``u`` (changes from the record's start), settings chosen by CV.

    ``fitted`` marks the samples that enter the fit (default: all); the
    model always runs through the whole record. The number of modes (1 ..
    ``max_modes``, default all) and the ridge weight are those of the best
    pooled leave-one-fold-out fit (within :data:`SELECTION_TOLERANCE_POINTS`,
    the simplest); the model is then refitted on every fitted sample. Only
    settings whose every input's static gain, times that input's range over the
    fitted samples, stays within ``max_reach_ratio`` times the output's range
    are eligible: beyond it, inputs balance each other with large opposite
    gains, which held-out cycles of the same programme do not expose but the
    next programme does. ``starts``: the first sample of each stacked
    experiment, where every lag restarts from rest (:mod:`compd.model.experiments`).
    """
    y, u, taus = checked_bank_data(y, u, time_constants_s)
    fitted = np.ones(y.size, dtype=bool) if fitted is None else np.asarray(fitted, dtype=bool)
    n_inputs = u.shape[1]
    modes = range(1, min(max_modes or n_inputs, n_inputs) + 1)
    weights = tuple(float(w) for w in ridge_weights)

    # Held-out squared errors of every (modes, weight) setting, fold by fold: sums, not
    # whole-record predictions, so memory stays one design's worth on week-long 1 Hz records.
    squared_error = {(m, w): 0.0 for m in modes for w in weights}
    scored = np.zeros(y.size, dtype=bool)
    designs = []
    for fold in range(folds.n_folds):
        held = fitted & (folds.labels == fold)
        train = fitted & (folds.labels != fold)
        if not held.any() or train.sum() < 2:
            continue
        scored |= held
        design = _Design(u, y, train, taus, sample_time_s, starts)
        designs.append((held, design))
        for m in modes:
            for w, coefficients in zip(weights, design.solve(m, weights), strict=True):
                residue = y[held] - design.predict(m, coefficients, held)
                squared_error[(m, w)] += float(residue @ residue)
        design.release()
    if not scored.any():
        raise ModelError("no fold has both held-out and fitted samples: cannot cross-validate")
    spread = float(np.linalg.norm(y[scored] - y[scored].mean()))
    if spread == 0.0:
        raise ModelError("the output does not vary on the held-out samples")
    design = _Design(u, y, fitted, taus, sample_time_s, starts)
    solutions = {
        (m, w): c for m in modes for w, c in zip(weights, design.solve(m, weights), strict=True)
    }
    reach = {
        key: _reach_ratio(design.gains(key[0], c), u[fitted], y[fitted])
        for key, c in solutions.items()
    }
    plausible = [key for key in solutions if reach[key] <= max_reach_ratio]
    if not plausible:  # even the strongest ridge leans on cancelling gains: the least of them
        plausible = [min(reach, key=reach.__getitem__)]
    scores = {key: 100.0 * (1.0 - np.sqrt(squared_error[key]) / spread) for key in plausible}
    best = max(scores.values())
    # Simplest within tolerance: fewest modes, then the largest ridge weight.
    n_modes, weight = min(
        (key for key, score in scores.items() if score >= best - SELECTION_TOLERANCE_POINTS),
        key=lambda key: (key[0], -key[1]),
    )
    coefficients = solutions[(n_modes, weight)]
    cv_predicted = np.full(y.size, np.nan)
    for held, fold_design in designs:  # the chosen setting's held-out predictions, again
        fold_design.restore(u, taus, sample_time_s)
        fold_coefficients = fold_design.solve(n_modes, [weight])[0]
        cv_predicted[held] = fold_design.predict(n_modes, fold_coefficients, held)
        fold_design.release()
    predicted = design.predict(n_modes, coefficients)
    return LagBankFit(
        time_constants_s=taus,
        gains=design.gains(n_modes, coefficients),
        n_modes=n_modes,
        ridge_weight=weight,
        fit_percent=float(fit_percent(y[fitted], predicted[fitted])),
        cv_fit_percent=scores[(n_modes, weight)],
        predicted_um=predicted,
        cv_predicted_um=cv_predicted,
    )


def _reach_ratio(gains: np.ndarray, u: np.ndarray, y: np.ndarray) -> float:
    """The largest ``|static gain| x input range`` over the output's range (inf for a flat output)."""
    output_range = float(np.ptp(y))
    reach = float(np.max(np.abs(gains.sum(axis=1)) * np.ptp(u, axis=0)))
    return reach / output_range if output_range > 0.0 else float("inf")


def regression_cv(
    y: np.ndarray, u: np.ndarray, folds: Folds, fitted: np.ndarray | None = None
) -> tuple[np.ndarray, float]:
    """The static regression ``y = sum k_i u_i`` (no intercept): its gains and cross-validated fit %."""
    y = np.asarray(y, dtype=float)
    u = np.asarray(u, dtype=float)

    def fit_predict(train: np.ndarray) -> np.ndarray:
        k, *_ = np.linalg.lstsq(u[train], y[train], rcond=None)
        return np.asarray(u @ k)

    prediction = cross_validated_prediction(fit_predict, folds, fitted)
    mask = np.ones(y.size, dtype=bool) if fitted is None else np.asarray(fitted, dtype=bool)
    gains, *_ = np.linalg.lstsq(u[mask], y[mask], rcond=None)
    return np.asarray(gains), pooled_fit_percent(y, prediction)
