"""The default lag bank: the static regression plus lags shrunk toward it, and nested cross-validation."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.signal
from numpy.testing import assert_allclose

from compd.files.modelschema import CrossValidationDoc
from compd.model.crossval import Folds, cycle_folds
from compd.model.lagbank import lag_features
from compd.model.nested import nested_prediction, scored_fit_percent
from compd.model.shrinkbank import (
    SHRINK_WEIGHTS,
    ShrunkBank,
    reaches_too_far,
    regression_written,
)
from compd.toolkit.nestedselect import CandidateScore, compare_candidates

DT_S = 60.0
TAUS = (0.0, 300.0, 1200.0, 3600.0, 10800.0)


def _cycles(rng: np.random.Generator, n: int = 6 * 480) -> tuple[np.ndarray, np.ndarray]:
    """Six 8 h spindle cycles (4 h on at a random speed, 4 h off) and three temperatures lagging it."""
    hours = np.arange(n) * DT_S / 3600.0
    level = rng.uniform(0.4, 1.6, 6)[np.minimum((hours // 8).astype(int), 5)]
    speed = np.where(hours % 8 < 4, level, 0.0)
    temps = []
    for tau in (900.0, 3600.0, 9000.0):
        pole = np.exp(-DT_S / tau)
        temps.append(scipy.signal.lfilter([0.0, 1.0 - pole], [1.0, -pole], 3.0 * speed))
    return speed, np.column_stack(temps) + rng.normal(0.0, 0.005, (n, 3))


def test_the_strongest_shrinkage_is_the_static_regression() -> None:
    """At the largest weight the lags carry almost nothing and the input gains are the regression's."""
    rng = np.random.default_rng(3)
    speed, u = _cycles(rng)
    y = u @ np.array([2.0, -1.0, 0.5]) + rng.normal(0.0, 0.05, speed.size)
    bank = ShrunkBank(y, u, sample_time_s=DT_S, folds=cycle_folds(speed), time_constants_s=TAUS)
    coefficients = bank._solve(list(bank.parts), [1e6], bank.columns(None))[0]
    gains = coefficients.reshape(len(TAUS), 3).T
    regression = np.linalg.lstsq(u, y, rcond=None)[0]
    assert_allclose(gains[:, 0], regression, rtol=1e-3, atol=1e-3)
    assert np.max(np.abs(gains[:, 1:])) < 1e-3


def test_a_lagged_plant_is_fitted_with_lags_and_holds_on_cycles_it_never_saw() -> None:
    """A drift that lags its sensors by 20 min: the bank keeps lags and its nested fit beats the regression's."""
    rng = np.random.default_rng(4)
    speed, u = _cycles(rng)
    y = lag_features(u, (1200.0,), DT_S) @ np.array([4.0, 2.0, -1.0])
    y += rng.normal(0.0, 0.02, y.size)
    folds = cycle_folds(speed)
    bank = ShrunkBank(y, u, sample_time_s=DT_S, folds=folds, time_constants_s=TAUS)
    nested = scored_fit_percent(y, nested_prediction(lambda t: bank.fit(t).predicted_um, folds))
    regression = compare_candidates(
        y, {"a": u[:, 0], "b": u[:, 1], "c": u[:, 2]}, sample_time_s=DT_S, folds=folds,
        candidates=("lagbank", "mlr"), time_constants_s=TAUS,
    )  # fmt: skip
    assert nested is not None and nested > 95.0
    assert regression.kept == "lagbank"
    score, baseline = regression.score("lagbank"), regression.score("mlr")
    assert score is not None and baseline is not None
    assert score.nested_fit_percent is not None and baseline.nested_fit_percent is not None
    assert score.nested_fit_percent > baseline.nested_fit_percent + 5.0


def test_where_the_regression_holds_as_well_the_default_keeps_the_regression() -> None:
    """A static plant with noise: the lags add nothing that holds fold by fold, so the regression is kept."""
    rng = np.random.default_rng(5)
    speed, u = _cycles(rng)
    y = u @ np.array([1.5, 0.5, -0.5]) + rng.normal(0.0, 0.3, speed.size)
    selection = compare_candidates(
        y, {"a": u[:, 0], "b": u[:, 1], "c": u[:, 2]}, sample_time_s=DT_S,
        folds=cycle_folds(speed), candidates=("lagbank", "mlr"), time_constants_s=TAUS,
    )  # fmt: skip
    assert selection.kept == "mlr"


def test_selection_is_deterministic() -> None:
    """The same data give the same weight, gains and figures, bit for bit."""
    rng = np.random.default_rng(6)
    speed, u = _cycles(rng)
    y = lag_features(u, (3600.0,), DT_S) @ np.array([1.0, 1.0, 1.0]) + rng.normal(
        0, 0.1, speed.size
    )
    fits = [
        ShrunkBank(y, u, sample_time_s=DT_S, folds=cycle_folds(speed), time_constants_s=TAUS).fit()
        for _ in range(2)
    ]
    assert fits[0].ridge_weight == fits[1].ridge_weight in SHRINK_WEIGHTS
    assert np.array_equal(fits[0].gains, fits[1].gains)
    assert fits[0].cv_fit_percent == fits[1].cv_fit_percent


def test_two_copies_of_a_sensor_are_not_balanced_against_each_other() -> None:
    """A near-duplicate sensor: the kept bank gives neither copy a large gain cancelled by the other."""
    rng = np.random.default_rng(7)
    speed, u = _cycles(rng)
    u = np.column_stack([u, u[:, 0] + rng.normal(0.0, 0.002, speed.size)])
    y = lag_features(u[:, :3], (1200.0,), DT_S) @ np.array([3.0, 1.0, 0.5])
    y += rng.normal(0.0, 0.2, y.size)
    fit = ShrunkBank(
        y, u, sample_time_s=DT_S, folds=cycle_folds(speed), time_constants_s=TAUS
    ).fit()
    reach = np.abs(fit.gains.sum(axis=1)) * np.ptp(u, axis=0)
    assert np.all(reach <= 3.0 * np.ptp(y))


def test_a_nested_fold_is_predicted_by_a_procedure_that_never_saw_it() -> None:
    """Every training set handed to the procedure leaves out the fold it then predicts."""
    labels = np.repeat(np.arange(4), 25)
    folds = Folds(labels, "blocks")
    seen: list[np.ndarray] = []

    def procedure(train: np.ndarray) -> np.ndarray:
        seen.append(train.copy())
        return np.full(labels.size, float(len(seen)))

    prediction = nested_prediction(procedure, folds)
    assert prediction is not None and len(seen) == 4
    for fold, train in enumerate(seen):
        assert not np.any(train & (labels == fold)) and np.all(train | (labels == fold))
        assert np.all(prediction[labels == fold] == fold + 1)
    assert nested_prediction(procedure, Folds(np.repeat(np.arange(2), 50), "halves")) is None


def test_a_regression_the_guard_rails_only_warn_about_stays_a_candidate() -> None:
    """A gain reaching 5x the output's range is a warning, not a refusal: the regression is still written."""
    u = np.linspace(0.0, 1.0, 50)[:, None]
    y = np.sin(np.linspace(0.0, 3.0, 50))
    output_range = float(np.ptp(y))
    assert not regression_written(y, u, np.array([12.0 * output_range]))
    assert regression_written(y, u, np.array([5.0 * output_range]))
    assert reaches_too_far(np.array([5.0 * output_range]), u, output_range)  # the warning


def test_the_expected_figure_is_the_median_of_the_held_out_folds() -> None:
    """Nested 80 % pooled over folds of 90, 75 and -170 % (a fold that barely moves): a typical new record, 75 %."""
    score = CandidateScore("lagbank", 95.0, 85.0, 80.0, (90.0, 75.0, -170.0))
    assert score.median_fold_percent == 75.0 and score.expected_percent == 75.0
    assert score.spread_percent == pytest.approx(float(np.std([90.0, 75.0, -170.0])))
    # One fold: nothing to take the median of, the pooled held-out figure.
    assert CandidateScore("mlr", 90.0, 75.0, 75.0, (75.0,)).expected_percent == 75.0


def test_an_older_file_expects_its_nested_figure_less_the_spread() -> None:
    """A provenance without the folds' median (written before it) keeps the figure it printed then."""
    doc = CrossValidationDoc(
        output="y",
        folds="leave one of 3 blocks out",
        kept="lagbank",
        nested_fit_percent={"lagbank": 80.0},
        fold_spread_percent={"lagbank": 8.0},
    )
    assert doc.expected_percent() == 72.0
    assert doc.expected_how() == " less its spread over the folds, 8.0 points"
    newer = doc.model_copy(update={"fold_median_percent": {"lagbank": 75.0}})
    assert newer.expected_percent() == 75.0
    assert newer.expected_how() == ": the median of its held-out folds, pooled 80.0 %"


def test_a_lag_bank_consistently_but_barely_better_is_not_kept() -> None:
    """Lags that add 0.4 points nested, fold by fold: less than a point does not pay for the dynamics' risk."""
    rng = np.random.default_rng(5)
    speed, u = _cycles(rng)
    lagged = lag_features(u[:, :1], (1800.0,), DT_S)[:, 0]
    y = u @ np.array([2.0, -1.0, 0.5]) + 0.35 * (lagged - u[:, 0])
    y += rng.normal(0.0, 0.05, speed.size)
    selection = compare_candidates(
        y, {"a": u[:, 0], "b": u[:, 1], "c": u[:, 2]}, sample_time_s=DT_S,
        folds=cycle_folds(speed), candidates=("lagbank", "mlr"), time_constants_s=TAUS,
    )  # fmt: skip
    score, baseline = selection.score("lagbank"), selection.score("mlr")
    assert score is not None and baseline is not None
    assert score.nested_fit_percent is not None and baseline.nested_fit_percent is not None
    assert 0.0 < score.nested_fit_percent - baseline.nested_fit_percent < 1.0
    assert selection.kept == "mlr"
