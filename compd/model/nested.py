"""Nested cross-validation: what a fitting procedure gives on data none of its choices saw.

Picking the best of many settings by the folds that score them fits the
folds: the figure printed is the maximum of noisy estimates, and the next
machine sees less (issue 20 measured 9-31 points less). The nested estimate
runs the *whole* procedure (its settings chosen by the folds inside the
training set) once per outer fold on the other folds only, and predicts the
held-out fold with it. Nothing of the held-out fold enters any choice, so the
pooled fit % of those predictions estimates the fit on new data of the same
kind.

A procedure is a function ``train -> prediction over the whole record``
(NaN allowed outside the held-out fold).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from compd.model.crossval import Folds
from compd.model.metrics import fit_percent

#: The nested estimate needs training sets that can themselves be cross-validated.
MIN_FOLDS_FOR_NESTED = 3

Procedure = Callable[[np.ndarray], np.ndarray]


def nested_prediction(
    procedure: Procedure, folds: Folds, fitted: np.ndarray | None = None
) -> np.ndarray | None:
    """Each outer fold's fitted samples predicted by ``procedure`` run on the other folds' only.

    None with fewer than :data:`MIN_FOLDS_FOR_NESTED` folds that hold fitted samples.
    """
    n = folds.labels.size
    fitted = np.ones(n, dtype=bool) if fitted is None else np.asarray(fitted, dtype=bool)
    present = [f for f in range(folds.n_folds) if np.any(fitted & (folds.labels == f))]
    if len(present) < MIN_FOLDS_FOR_NESTED:
        return None
    prediction = np.full(n, np.nan)
    for fold in present:
        held = fitted & (folds.labels == fold)
        prediction[held] = procedure(fitted & (folds.labels != fold))[held]
    return prediction


def scored_fit_percent(measured: np.ndarray, predicted: np.ndarray | None) -> float | None:
    """Fit % over the samples that have a prediction; None without two of them."""
    if predicted is None:
        return None
    scored = np.isfinite(predicted)
    if scored.sum() < 2:
        return None
    value = float(fit_percent(measured[scored], predicted[scored]))
    return value if np.isfinite(value) else None
