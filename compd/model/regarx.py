"""Regularised ARX as a candidate of the default fit: one shared second-order denominator, ridge-shrunk.

The lag bank (:mod:`compd.model.lagbank`) fixes its time constants; a
machine whose drift lags its sensors by a day, or leads them, is better
fitted by a model that finds its own poles. MISO ARX (:mod:`compd.model.arx`)
does, but at 16 collinear inputs its least-squares numerators balance each
other like any free regression. So here ARX at ``na = nb = 2`` (two shared
poles, two numerator terms per input, delay one sample) is fitted with a
ridge penalty on its delta-basis coefficients scaled to unit diagonal
(MATLAB's ``arxRegul`` regularises the same normal equations with a kernel;
a scaled identity is its simplest member), the weight chosen from a few by
leave-one-fold-out free-run fit. An unstable solution scores nothing.

The normal equations are summed per fold once, so every training set the
selection asks for (unions of folds) costs a few small solves.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from compd.model.arx import ArxParameters, Regression, regression_matrix, simulate_arx, solve_arx
from compd.model.crossval import Folds
from compd.model.experiments import ONE, spans

#: Two shared poles, two numerator coefficients per input.
ARX_ORDER = 2
#: Ridge weights on the unit-diagonal normal equations, tried by cross-validation.
ARX_RIDGE_WEIGHTS: tuple[float, ...] = (1e-4, 1e-3, 1e-2, 1e-1)
#: Rows per block when summing the normal equations.
_BLOCK = 16_384


@dataclass(frozen=True, eq=False)
class ArxFit:
    """Regularised ARX fitted on some folds: parameters, weight, and its predictions."""

    parameters: ArxParameters
    ridge_weight: float
    predicted_um: np.ndarray = field(repr=False)  # refitted on every training fold, whole record
    cv_predicted_um: np.ndarray = field(repr=False)  # held-out predictions of the chosen weight


class ArxDesign:
    """Per-fold delta-basis normal equations of one record (or stacked experiments)."""

    def __init__(
        self,
        y: np.ndarray,
        u: np.ndarray,
        folds: Folds,
        fitted: np.ndarray,
        starts: Sequence[int] = ONE,
        order: int = ARX_ORDER,
    ) -> None:
        self.u = np.asarray(u, dtype=float)
        self.starts = tuple(starts)
        self.order = order
        self.n_inputs = self.u.shape[1]
        self.folds = folds
        self.grams: dict[int, np.ndarray] = {}
        self.offsets: dict[tuple[int, int], int] = {}
        self.first_row = 0
        for part in spans(y.size, self.starts):
            yp, up = np.asarray(y[part], dtype=float), self.u[part]
            if yp.size <= 2 * order + 2:
                continue
            for start in range(0, yp.size, _BLOCK):
                matrix, self.offsets, first = regression_matrix(
                    yp,
                    up,
                    na_max=order,
                    nb_max=order,
                    delays=(1,),
                    rows=(start, min(start + _BLOCK, yp.size)),
                )
                self.first_row = first
                rows = np.arange(max(start, first), min(start + _BLOCK, yp.size)) + part.start
                keep = fitted[rows]
                for fold in np.unique(folds.labels[rows][keep]):
                    block = matrix[keep & (folds.labels[rows] == fold)]
                    product = block.T @ block
                    self.grams[int(fold)] = self.grams.get(int(fold), 0.0) + product

    def solve(self, train_folds: Sequence[int], weight: float) -> ArxParameters | None:
        """Ridge ARX on the normal equations of ``train_folds``; None if unstable or empty."""
        present = [f for f in train_folds if f in self.grams]
        if not present:
            return None
        gram = sum(self.grams[f] for f in present)
        scale = np.sqrt(np.diag(gram))
        scale[scale == 0.0] = 1.0
        scaled = gram / scale[:, None] / scale[None, :]
        penalty = np.full(scaled.shape[0], weight)
        penalty[0] = 0.0  # the target's own column
        regularised = (scaled + np.diag(penalty)) * scale[:, None] * scale[None, :]
        regression = Regression(regularised, self.order, self.order, (1,), self.offsets, 1)
        n = self.n_inputs
        try:
            parameters = solve_arx(regression, self.order, [self.order] * n, [1] * n)
        except (np.linalg.LinAlgError, ValueError):
            return None
        return parameters if parameters.stable() else None

    def simulate(self, parameters: ArxParameters) -> np.ndarray:
        return simulate_arx(parameters, self.u, self.starts)

    def fit(
        self, y: np.ndarray, train: np.ndarray, weights: Sequence[float] = ARX_RIDGE_WEIGHTS
    ) -> ArxFit | None:
        """The weight of the best pooled held-out fit over the folds inside ``train``, refitted on them.

        None when no weight gives a stable model on every inner fold.
        """
        labels = self.folds.labels
        inner = sorted(int(f) for f in np.unique(labels[train]) if int(f) in self.grams)
        if len(inner) < 2:
            return None
        best: tuple[float, float, np.ndarray] | None = None
        for weight in weights:
            cv = np.full(y.size, np.nan)
            for fold in inner:
                parameters = self.solve([f for f in inner if f != fold], weight)
                if parameters is None:
                    break
                held = train & (labels == fold)
                cv[held] = self.simulate(parameters)[held]
            else:
                scored = np.isfinite(cv)
                error = float(np.sum((y[scored] - cv[scored]) ** 2))
                if best is None or error < best[0]:
                    best = (error, weight, cv)
        if best is None:
            return None
        _, weight, cv = best
        parameters = self.solve(inner, weight)
        if parameters is None:
            return None
        return ArxFit(parameters, weight, self.simulate(parameters), cv)
