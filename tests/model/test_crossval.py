"""Leave-one-cycle-out folds: whole operating cycles held out, the model run through the whole record."""

from __future__ import annotations

import numpy as np
import pytest

from compd.errors import ModelError
from compd.model.crossval import (
    blocked_folds,
    cross_validated_prediction,
    cycle_folds,
    pooled_fit_percent,
)


def _cycles(n_cycles: int, on: int = 40, off: int = 40, lead_in: int = 10) -> np.ndarray:
    return np.concatenate([np.zeros(lead_in), *([np.ones(on), np.zeros(off)] * n_cycles)])


def test_each_cycle_is_a_fold_and_the_lead_in_joins_the_first() -> None:
    """Four heat/cool cycles make four folds, each from a spindle start to the next."""
    folds = cycle_folds(_cycles(4), name="spindle_speed_rpm")
    assert folds.n_folds == 4
    assert np.bincount(folds.labels).tolist() == [90, 80, 80, 80]
    assert "spindle_speed_rpm" in folds.describe()


def test_many_cycles_are_merged_into_whole_cycle_folds() -> None:
    """A production record of twenty short cycles gives at most six folds, none splitting a cycle."""
    signal = _cycles(20, on=25, off=25)
    folds = cycle_folds(signal, max_folds=6)
    assert folds.n_folds == 6
    starts = np.flatnonzero(np.diff(folds.labels)) + 1
    assert all(signal[s] > 0 and signal[s - 1] == 0 for s in starts)


def test_a_record_without_cycles_falls_back_to_blocks() -> None:
    """One long run (no repeated starts) is cut into four contiguous blocks."""
    folds = cycle_folds(np.ones(400))
    assert folds.n_folds == 4 and "blocks" in folds.kind
    assert np.all(np.diff(folds.labels) >= 0)


def test_a_short_record_is_cut_into_fewer_blocks() -> None:
    """74 samples (a 6 h warm-up at 5 min) make three blocks of at least 20, not a refusal."""
    folds = blocked_folds(74)
    assert folds.n_folds == 3
    assert np.bincount(folds.labels).min() >= 20
    assert blocked_folds(45).n_folds == 2
    assert blocked_folds(4000).n_folds == 4


def test_too_short_a_record_is_refused() -> None:
    """Fewer than two blocks of 20 samples cannot be cross-validated."""
    with pytest.raises(ModelError, match="too few"):
        blocked_folds(30)


def test_held_out_samples_never_enter_their_own_fit() -> None:
    """The fit that predicts a fold saw none of its samples."""
    folds = cycle_folds(_cycles(4))
    seen: list[np.ndarray] = []

    def fit_predict(train: np.ndarray) -> np.ndarray:
        seen.append(train.copy())
        return np.where(train, np.nan, 1.0)  # NaN wherever a training sample would leak

    prediction = cross_validated_prediction(fit_predict, folds)
    assert np.all(prediction == 1.0) and len(seen) == folds.n_folds
    assert pooled_fit_percent(np.arange(prediction.size, dtype=float), prediction) < 0
