"""The default lag bank: the static regression plus lags shrunk toward it, one weight, 1-SE rule.

The lag bank of :mod:`compd.model.lagbank` chose 16 modes x 11 ridge weights
by 3-4 folds: the choice fitted the folds, and on machines no one tuned it on
it lost to the static regression it was meant to beat (issue 20). This bank
has one hyperparameter and a safe end:

- each input (as a change from start) drives lags at fixed time constants
  (default 0, 5 min, 20 min, 1 h, 3 h), on the raw sensors (no principal
  directions);
- the lag-0 columns, the input itself, are **not** penalised: they are the
  controllers' static regression ``y = sum k_i u_i``. Only the lagged columns
  (standardised) carry a ridge penalty ``w * n``; as ``w`` grows the model
  becomes exactly the regression. So the penalty shrinks the dynamics toward
  the baseline it must beat, not toward zero;
- ``w`` is chosen by leave-one-fold-out fit among :data:`SHRINK_WEIGHTS` with
  the standard-error rule (Hastie, Tibshirani, Friedman, sect. 7.10) at
  :data:`WEIGHT_STANDARD_ERRORS`: the largest weight whose held-out error is
  within two standard errors of the best. Selection noise on a few folds is
  that size, and the more shrunk model travels better to a programme the
  calibration did not run (on the random machines, two standard errors
  rather than one: not below the regression on 75 % of machines instead of
  72 %, the real record's ch3/ch4 74.5 / 75.0 % nested instead of 73.5 / 74.1 %).

On 100 random machines of the twin (``benchmarks/bench_machines.py``,
verify data on another programme) the default built on it is not below the
regression on unseen data on 72 % of them, against 54 % for the
principal-direction bank of :mod:`compd.model.lagbank` (benchmarks/README.md).

Everything is linear least squares on Gram matrices summed per fold once, so
any training set that is a union of folds (the nested estimate's) costs a few
small solves.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from compd.errors import ModelError
from compd.model.crossval import Folds
from compd.model.experiments import ONE
from compd.model.guards import (
    CANCEL_SIZE_RATIO,
    CANCEL_SUM_FRACTION,
    GAIN_ERROR_RATIO,
    GAIN_WARNING_RATIO,
)
from compd.model.lagbank import (
    DEFAULT_TIME_CONSTANTS_S,
    LagBankFit,
    checked_bank_data,
    lag_features,
)
from compd.model.metrics import fit_percent

#: Penalty weights on the standardised lag columns, relative to the number of fitted samples.
SHRINK_WEIGHTS: tuple[float, ...] = tuple(float(w) for w in np.logspace(-5, 1, 13))
#: The weight is the largest whose pooled held-out error is within this many standard errors
#: (over the folds) of the best weight's.
WEIGHT_STANDARD_ERRORS = 2.0


class ShrunkBank:
    """The lag features of one record and their normal equations per fold, ready to fit any union of folds."""

    def __init__(
        self,
        y: np.ndarray,
        u: np.ndarray,
        *,
        sample_time_s: float,
        folds: Folds,
        fitted: np.ndarray | None = None,
        time_constants_s: Sequence[float] = DEFAULT_TIME_CONSTANTS_S,
        starts: Sequence[int] = ONE,
        new_recordings: bool = False,
        input_ranges: Sequence[float] | np.ndarray | None = None,
    ) -> None:
        y, u, taus = checked_bank_data(y, u, time_constants_s)
        self.y = y
        self.taus = taus
        self.n_inputs = u.shape[1]
        # The inputs' calibration ranges as the guard rails measure them (the raw columns': over
        # several files wider than the changes from each file's start); None: the changes'.
        self.input_ranges = None if input_ranges is None else np.asarray(input_ranges, float)
        self.folds = folds
        self.fitted = np.ones(y.size, dtype=bool) if fitted is None else np.asarray(fitted, bool)
        self.features = lag_features(u, taus, sample_time_s, starts)
        # How held-out samples are judged: by default as the record continued (the model run
        # through it, its state carried: leave-one-cycle-out as compd defines it); with
        # ``new_recordings`` each fold as a new recording, run from rest at its start with inputs
        # and displacement as changes from there (a fold that is a whole file already is one).
        self.fresh_u, self.fresh_y, self.fresh_features = u, y, self.features
        if new_recordings:
            cuts = fresh_starts(folds, starts)
            self.fresh_u = u - _first_of_segment(u, cuts)
            self.fresh_y = y - np.where(
                np.isin(_segment_start(y.size, cuts), starts), 0.0, _first_of_segment(y, cuts)
            )
            self.fresh_features = lag_features(self.fresh_u, taus, sample_time_s, cuts)
        penalised = np.repeat([t != 0.0 for t in taus], self.n_inputs)
        self.penalty = penalised.astype(float)
        # Per fold over its fitted samples: count, sums, sums of squares, Gram matrix, X^T y.
        self.parts: dict[int, tuple[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = {}
        for fold in range(folds.n_folds):
            rows = self.fitted & (folds.labels == fold)
            if rows.any():
                block = self.features[rows]
                self.parts[fold] = (
                    int(rows.sum()),
                    block.sum(axis=0),
                    (block * block).sum(axis=0),
                    block.T @ block,
                    block.T @ y[rows],
                )

    def columns(self, inputs: Sequence[int] | None) -> np.ndarray:
        """Feature columns of ``inputs`` (indices; None: all) at every time constant."""
        if inputs is None:
            return np.arange(self.features.shape[1])
        chosen = np.asarray(list(inputs), dtype=int)
        return np.concatenate([chosen + j * self.n_inputs for j in range(len(self.taus))])

    def _solve(
        self, train_folds: Sequence[int], weights: Sequence[float], columns: np.ndarray
    ) -> list[np.ndarray]:
        """Coefficients (on the unscaled features of ``columns``) per weight, fitted on ``train_folds``."""
        parts = [self.parts[f] for f in train_folds]
        n = sum(p[0] for p in parts)
        mean = sum(p[1][columns] for p in parts) / n
        variance = sum(p[2][columns] for p in parts) / n - mean * mean
        scale = np.sqrt(np.maximum(variance, 0.0))
        scale[scale <= 1e-12 * max(float(scale.max()), 1e-300)] = 1.0
        index = np.ix_(columns, columns)
        gram = sum(p[3][index] for p in parts) / np.outer(scale, scale)
        rhs = sum(p[4][columns] for p in parts) / scale
        # A whisker on every column keeps duplicate sensors solvable (their sum is what is fitted).
        floor = 1e-9 * max(float(np.mean(np.diag(gram))), 1e-300)
        penalty = self.penalty[columns]
        return [
            np.linalg.solve(gram + np.diag(penalty * weight * n + floor), rhs) / scale
            for weight in weights
        ]

    def predict(
        self, coefficients: np.ndarray, columns: np.ndarray, rows: np.ndarray | None = None
    ) -> np.ndarray:
        features = (
            self.features[:, columns] if rows is None else self.features[np.ix_(rows, columns)]
        )
        return np.asarray(features @ coefficients)

    def fit(
        self, train: np.ndarray | None = None, inputs: Sequence[int] | None = None
    ) -> LagBankFit:
        """The bank on the samples ``train`` (default: every fitted one), its weight by the folds inside.

        ``inputs``: the indices of the inputs it uses (default all; the
        others get zero gains). The weight is the largest within
        :data:`WEIGHT_STANDARD_ERRORS` standard errors of the best pooled
        held-out error (:data:`SHRINK_WEIGHTS`); with fewer than two folds
        inside ``train`` it is the largest (the regression, nearly).
        """
        train = self.fitted if train is None else np.asarray(train, dtype=bool) & self.fitted
        columns = self.columns(inputs)
        labels = self.folds.labels
        inner = [f for f in self.parts if np.any(train & (labels == f))]
        if not inner:
            raise ModelError("no fitted samples to fit the lag bank on")
        weights = SHRINK_WEIGHTS
        cv_predicted = np.full(self.y.size, np.nan)
        cv_percent = None
        solutions = self._solve(inner, weights, columns)
        eligible = [plausible(self, c, columns, train) for c in solutions]
        if not any(eligible):
            if np.any(self.penalty == 0.0):  # the regression part itself balances collinear inputs
                return self._fit_all_penalised(train, inputs)
            # Nothing passes even fully penalised (an output that barely moves): the strongest
            # shrinkage, and the guard rails judge the written model.
            eligible[-1] = True
        chosen = int(np.flatnonzero(eligible).max())
        if len(inner) >= 2:
            errors = np.zeros((len(inner), len(weights)))
            held_out = []
            for i, fold in enumerate(inner):
                held = train & (labels == fold)
                trained = self._solve([f for f in inner if f != fold], weights, columns)
                predictions = self.fresh_features[np.ix_(held, columns)] @ np.column_stack(trained)
                errors[i] = np.sum((self.fresh_y[held, None] - predictions) ** 2, axis=0)
                held_out.append((held, predictions))
            total = np.where(eligible, errors.sum(axis=0), np.inf)
            best = int(np.argmin(total))
            standard_error = WEIGHT_STANDARD_ERRORS * float(
                np.std(errors[:, best]) * np.sqrt(len(inner))
            )
            chosen = int(np.flatnonzero(total <= total[best] + standard_error).max())
            for held, predictions in held_out:
                cv_predicted[held] = predictions[:, chosen]
            scored = np.isfinite(cv_predicted)
            cv_percent = float(fit_percent(self.fresh_y[scored], cv_predicted[scored]))
        coefficients = np.zeros(self.features.shape[1])
        coefficients[columns] = solutions[chosen]
        predicted = self.predict(coefficients[columns], columns)
        gains = coefficients.reshape(len(self.taus), self.n_inputs).T  # (input, tau)
        return LagBankFit(
            time_constants_s=self.taus,
            gains=np.asarray(gains),
            n_modes=self.n_inputs,
            ridge_weight=weights[chosen],
            fit_percent=float(fit_percent(self.y[train], predicted[train])),
            cv_fit_percent=cv_percent,
            predicted_um=predicted,
            cv_predicted_um=cv_predicted,
        )

    def fresh_prediction(self, fit: LagBankFit) -> np.ndarray:
        """``fit``'s output with every fold run as a new recording (compare with :attr:`fresh_y`)."""
        return np.asarray(self.fresh_features @ fit.gains.T.reshape(-1))

    def _fit_all_penalised(self, train: np.ndarray, inputs: Sequence[int] | None) -> LagBankFit:
        """The fallback when even the regression part is implausible: the input itself penalised too."""
        saved = self.penalty
        self.penalty = np.ones_like(saved)
        try:
            return self.fit(train, inputs)
        finally:
            self.penalty = saved


def fresh_starts(folds: Folds, starts: Sequence[int]) -> tuple[int, ...]:
    """Where a new recording starts: every experiment's start and every fold boundary."""
    boundaries = np.flatnonzero(np.diff(folds.labels) != 0) + 1
    return tuple(sorted({0, *(int(s) for s in starts), *(int(b) for b in boundaries)}))


def _segment_start(n: int, cuts: Sequence[int]) -> np.ndarray:
    """Each sample's segment start (the last cut at or before it)."""
    bounds = np.asarray(cuts)
    return np.asarray(bounds[np.searchsorted(bounds, np.arange(n), side="right") - 1])


def _first_of_segment(x: np.ndarray, cuts: Sequence[int]) -> np.ndarray:
    """Each sample's segment's first value (rows of ``x``)."""
    return np.asarray(x[_segment_start(len(x), cuts)])


def plausible(
    bank: ShrunkBank, coefficients: np.ndarray, columns: np.ndarray, train: np.ndarray
) -> bool:
    """The guard rails (:mod:`compd.model.guards`) on a candidate's coefficients, over ``train``.

    No input's static gain times its range beyond :data:`GAIN_WARNING_RATIO`
    times the output's range, and no two inputs' contributions each
    :data:`CANCEL_SIZE_RATIO` times the model's yet cancelling: the model
    ``compd fit`` would refuse or warn about is not a candidate.
    """
    n_taus = len(bank.taus)
    per_input = np.zeros((bank.n_inputs, n_taus))
    full = np.zeros(bank.features.shape[1])
    full[columns] = coefficients
    per_input[:] = full.reshape(n_taus, bank.n_inputs).T
    used = np.flatnonzero(np.any(per_input != 0.0, axis=1))
    y = bank.y[train]
    output_range = float(np.ptp(y)) if y.size else 0.0
    if output_range <= 0.0 or used.size == 0:
        return True
    features = bank.features[train]
    if 0.0 in bank.taus:  # the inputs themselves are among the features
        first = bank.taus.index(0.0) * bank.n_inputs
        inputs = features[:, first + used]
        ranges = None if bank.input_ranges is None else bank.input_ranges[used]
        if reaches_too_far(per_input[used].sum(axis=1), inputs, output_range, ranges=ranges):
            return False
    terms = np.column_stack(
        [features[:, [j * bank.n_inputs + i for j in range(n_taus)]] @ per_input[i] for i in used]
    )
    return not cancelling(terms)


def regression_written(
    y: np.ndarray, u: np.ndarray, gains: np.ndarray, input_ranges: np.ndarray | None = None
) -> bool:
    """Whether ``compd fit`` writes the static regression ``y = u @ gains`` (rows given) unforced.

    Its guard rails refuse a gain beyond :data:`GAIN_ERROR_RATIO` times the
    output's range and cancelling pairs; a gain beyond the warning ratio is
    written with a warning (the regression is the controllers' own model: a
    warning does not make the lag bank, which may travel worse, the choice).
    """
    output_range = float(np.ptp(y))
    if output_range <= 0.0:
        return True
    reach = reaches_too_far(gains, u, output_range, GAIN_ERROR_RATIO, ranges=input_ranges)
    return not reach and not cancelling(u * gains)


def reaches_too_far(
    static_gains: np.ndarray,
    inputs: np.ndarray,
    output_range: float,
    ratio: float = GAIN_WARNING_RATIO,
    *,
    ranges: np.ndarray | None = None,
) -> bool:
    """Whether an input's static gain times its range exceeds ``ratio`` times the output's range.

    The range is the inputs' spread, or ``ranges`` where that is wider (the raw
    columns' over several files, as :func:`compd.model.guards.check_model` measures).
    """
    spread = np.ptp(inputs, axis=0)
    if ranges is not None:
        spread = np.maximum(spread, ranges)
    reach = np.abs(static_gains) * spread
    return bool(np.any(reach > ratio * output_range))


def cancelling(terms: np.ndarray) -> bool:
    """Whether two columns of ``terms`` (contributions) are each large against their sum and cancel."""
    rms = np.sqrt(np.mean(terms**2, axis=0))
    size = float(np.sqrt(np.mean(terms.sum(axis=1) ** 2)))
    big = np.flatnonzero(rms >= CANCEL_SIZE_RATIO * size)
    for a_index, a in enumerate(big):
        for b in big[a_index + 1 :]:
            together = float(np.sqrt(np.mean((terms[:, a] + terms[:, b]) ** 2)))
            if together < CANCEL_SUM_FRACTION * max(rms[a], rms[b]):
                return True
    return False
