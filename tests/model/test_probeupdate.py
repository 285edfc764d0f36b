"""The probe update (compd.model.probeupdate): a Kalman filter over a model's gains and bias, with rails."""

from __future__ import annotations

import numpy as np
import pytest

from compd.errors import ModelError
from compd.model.probesettings import ProbeSettings
from compd.model.probeupdate import REACH, ProbeUpdater
from compd.model.updateprior import (
    BIAS,
    DEFAULT_PRIOR_GAIN_SCALE,
    Prior,
    calibration_prior,
    default_prior,
    effective_samples,
)

NAMES = ("a", "b", BIAS)


def _contributions(n: int, seed: int = 0) -> np.ndarray:
    """Two slow, distinct contributions (um), as a thermal model's sub-models give."""
    t = np.arange(n) * 60.0
    rng = np.random.default_rng(seed)
    return np.column_stack(
        [
            20.0 * (1 - np.exp(-t / 7200.0)) + 3.0 * np.sin(t / 5000.0),
            -8.0 * np.sin(t / 3000.0 + rng.uniform(0, 1)) + 2.0,
        ]
    )


def _updater(**overrides: float) -> ProbeUpdater:
    prior = Prior(NAMES, np.diag([0.25, 0.25, 4.0]), residue_sigma_um=1.0)
    return ProbeUpdater(prior, ProbeSettings.defaults(prior, **overrides))


def test_gains_converge_to_the_truth_of_a_linear_system() -> None:
    """Probes of y = 1.4 c1 + 0.7 c2 + 2 um (noise 0.5 um) bring the gains and bias to the truth."""
    c = _contributions(2000)
    truth = np.array([1.4, 0.7, 2.0])
    x = np.column_stack([c, np.ones(len(c))])
    rng = np.random.default_rng(1)
    updater = _updater(drift_um_per_sqrt_h=0.0, max_departure_um=100.0)
    for i in range(5, len(c), 20):
        updater.probe(i * 60.0, x[i], float(x[i] @ truth + rng.normal(0, 0.5)))
    np.testing.assert_allclose(updater.theta, truth, atol=0.1)


def test_a_mis_probe_of_50_um_is_rejected_and_changes_nothing() -> None:
    """A single probe 50 um off is flagged and not used: the parameters stay as they were."""
    c = _contributions(400)
    x = np.column_stack([c, np.ones(len(c))])
    updater = _updater()
    for i in range(10, 200, 20):
        updater.probe(i * 60.0, x[i], float(x[i] @ updater.prior.mean))
    theta = updater.theta.copy()
    (step,) = updater.probe(210 * 60.0, x[210], float(x[210] @ theta) + 50.0)
    assert step.result == "flagged"
    assert step.innovation_after_um == step.innovation_before_um
    np.testing.assert_array_equal(updater.theta, theta)
    # The next probe agrees with the model: the flagged one is rejected for good.
    steps = updater.probe(230 * 60.0, x[230], float(x[230] @ theta))
    assert [s.result for s in steps] == ["rejected", "accepted"]
    np.testing.assert_allclose(updater.theta, theta, atol=1e-9)


def test_a_confirmed_jump_is_taken() -> None:
    """Two probes in a row 30 um above the model (same sign): both taken, the model follows the jump."""
    c = _contributions(400)
    x = np.column_stack([c, np.ones(len(c))])
    updater = _updater(max_departure_um=100.0)
    for i in range(10, 200, 20):
        updater.probe(i * 60.0, x[i], float(x[i] @ updater.prior.mean))
    truth = updater.prior.mean + np.array([0.0, 0.0, 30.0])
    (first,) = updater.probe(210 * 60.0, x[210], float(x[210] @ truth))
    assert first.result == "flagged"
    steps = updater.probe(230 * 60.0, x[230], float(x[230] @ truth))
    assert [s.result for s in steps] == ["confirmed", "confirmed"]
    assert abs(steps[-1].innovation_after_um) < 3.0
    assert abs(float(x[250] @ updater.theta) - float(x[250] @ truth)) < 3.0


def test_the_departure_bound_and_the_gain_rails_hold() -> None:
    """However far the probes pull, the prediction at a probe stays within the bound of the calibration's."""
    c = _contributions(400)
    x = np.column_stack([c, np.ones(len(c))])
    updater = _updater(max_departure_um=3.0, reject_sigma=1e9)
    for i in range(10, 400, 20):
        (step,) = updater.probe(i * 60.0, x[i], float(x[i] @ updater.prior.mean) + 40.0)
        departure = float(x[i] @ updater.theta - x[i] @ updater.prior.mean)
        assert abs(departure) <= 3.0 + 1e-9
        assert step.innovation_after_um >= 40.0 - 3.0 - 1e-9
        assert np.all((updater.theta[:-1] >= 0.0) & (updater.theta[:-1] <= 3.0))


def test_probes_out_of_time_order_are_refused() -> None:
    """A probe older than the last one taken is a ModelError, not a silent mix-up."""
    updater = _updater()
    updater.probe(100.0, np.array([1.0, 1.0, 1.0]), 2.0)
    with pytest.raises(ModelError, match="time order"):
        updater.probe(50.0, np.array([1.0, 1.0, 1.0]), 2.0)


def test_the_calibration_prior_is_the_inflated_ridge_posterior() -> None:
    """P0 = ((n_eff/n) X'X / s^2 + L)^-1: a (3, 3) SPD matrix, widened by the residue's autocorrelation, within L^-1."""
    c = _contributions(3000)
    rng = np.random.default_rng(2)
    white = rng.normal(0, 1.0, len(c))
    correlated = np.convolve(white, np.ones(50) / np.sqrt(50), mode="same")
    independent = calibration_prior(NAMES, c, white)
    autocorrelated = calibration_prior(NAMES, c, correlated)
    for prior in (independent, autocorrelated):
        assert prior.covariance.shape == (3, 3)
        np.testing.assert_allclose(prior.covariance, prior.covariance.T)
        assert np.all(np.linalg.eigvalsh(prior.covariance) > 0)
    assert independent.effective_samples > 0.5 * len(c)
    assert autocorrelated.effective_samples < len(c) / 20
    # Same residue size: the autocorrelated residue's prior is wider by about n / n_eff.
    ratio = np.diag(autocorrelated.covariance) / np.diag(independent.covariance)
    assert np.all(ratio > 10)
    x = np.column_stack([c, np.ones(len(c))])
    s2 = np.var(correlated)
    expected = np.linalg.inv(
        autocorrelated.effective_samples / len(c) * x.T @ x / s2
        + np.diag([1.0, 1.0, 0.0]) / DEFAULT_PRIOR_GAIN_SCALE**2
    )
    np.testing.assert_allclose(autocorrelated.covariance, expected, rtol=1e-8)


def test_effective_samples_of_white_and_ar1_noise() -> None:
    """White noise: n_eff near n; AR(1) with rho 0.9: near n (1 - rho) / (1 + rho)."""
    rng = np.random.default_rng(3)
    n = 20000
    white = rng.normal(size=n)
    assert effective_samples(white) == pytest.approx(n, rel=0.15)
    ar = np.empty(n)
    ar[0] = 0.0
    for i in range(1, n):
        ar[i] = 0.9 * ar[i - 1] + white[i]
    assert effective_samples(ar) == pytest.approx(n * 0.1 / 1.9, rel=0.3)


def test_the_default_prior_is_conservative_and_says_so() -> None:
    """Without a stored prior: gains 1 +- 0.3, bias 0 +- 2x the calibration RMS, source 'default'."""
    prior = default_prior(NAMES, calibration_rms_um=1.5)
    np.testing.assert_allclose(np.sqrt(np.diag(prior.covariance)), [0.3, 0.3, 3.0])
    assert prior.source == "default"
    np.testing.assert_array_equal(prior.mean, [1.0, 1.0, 0.0])


def test_one_update_at_80_parameters_is_cheap() -> None:
    """An update at 81 parameters runs (its cost is printed by benchmarks/bench_probes.py, not asserted)."""
    names = (*(f"g{i}" for i in range(80)), BIAS)
    prior = default_prior(names, 1.0)
    updater = ProbeUpdater(prior, ProbeSettings.defaults(prior))
    x = np.ones(81)
    steps = updater.probe(0.0, x, 1.0)
    assert steps[0].result in ("accepted", "flagged")


def test_the_departure_bound_holds_over_the_time_since_the_last_probe() -> None:
    """Given the regressors since the last probe, no update takes the prediction there beyond the bound.

    (Where the parameters before the update were already beyond it, as the
    regressors moved on, the update does not take them further.)
    """
    c = _contributions(400)
    x = np.column_stack([c, np.ones(len(c))])
    updater = _updater(max_departure_um=3.0, reject_sigma=1e9)
    mean = updater.prior.mean
    last = 0
    for i in range(20, 400, 20):
        rows = x[last : i + 1]
        limit = np.maximum(3.0, np.abs(rows @ (updater.theta - mean)))
        updater.probe(i * 60.0, x[i], float(x[i] @ mean) + 0.5 * c[i, 0], recent=rows)
        assert np.all(np.abs(rows @ (updater.theta - mean)) <= limit + 1e-9)
        last = i


def test_an_update_moves_no_recent_prediction_by_more_than_twice_the_innovation() -> None:
    """Over the time since the last probe, an update moves the prediction at most REACH times the innovation."""
    rng = np.random.default_rng(4)
    names = (*(f"g{i}" for i in range(8)), BIAS)
    prior = Prior(names, 0.09 * np.eye(9), residue_sigma_um=1.0)
    updater = ProbeUpdater(prior, ProbeSettings.defaults(prior, reject_sigma=1e9))
    rows = np.column_stack([rng.normal(0, 10, (100, 8)), np.ones(100)])
    for k in range(1, 10):
        before = updater.theta.copy()
        recent = rows[10 * (k - 1) : 10 * k + 1]
        (step,) = updater.probe(
            k * 3600.0, recent[-1], float(recent[-1] @ before) + 5.0, recent=recent
        )
        moved = np.abs(recent @ (updater.theta - before))
        assert np.max(moved) <= REACH * abs(step.innovation_before_um) + 1e-9


def _state(updater: ProbeUpdater) -> tuple[object, ...]:
    return (
        updater.theta.tolist(),
        updater.covariance.tolist(),
        updater.last_time_s,
        updater.drifted_to_s,
        updater.pending,
    )


@pytest.mark.parametrize("measured_um", [1e308, -2000.0, 1001.0])
def test_a_value_beyond_what_a_thermal_error_can_be_is_refused_and_changes_nothing(
    measured_um: float,
) -> None:
    """Beyond 1 mm (a typo, mm for um, an attack): a ModelError naming the bound, the state as before."""
    updater = _updater()
    x = np.array([10.0, 2.0, 1.0])
    updater.probe(0.0, x, 13.0)
    before = _state(updater)
    with pytest.raises(ModelError, match="beyond what a thermal error can be"):
        updater.probe(3600.0, x, measured_um)
    assert _state(updater) == before


def test_the_probe_bound_is_ten_calibration_peaks_where_that_is_below_1_mm() -> None:
    """A model whose largest output was 30 um: a probe of 301 um is refused, 299 um is not."""
    prior = Prior(NAMES, np.diag([0.25, 0.25, 4.0]), residue_sigma_um=1.0, output_peak_um=30.0)
    updater = ProbeUpdater(prior, ProbeSettings.defaults(prior))
    with pytest.raises(ModelError, match=r"\(300 um: 1 mm, or 10 times"):
        updater.probe(0.0, np.array([10.0, 2.0, 1.0]), 301.0)
    assert updater.probe(0.0, np.array([10.0, 2.0, 1.0]), 299.0)[0].result == "flagged"


def test_an_update_that_is_not_finite_is_taken_back_and_refused() -> None:
    """A regressor whose variance overflows (1e200 um): a ModelError, the parameters as before, never NaN."""
    updater = _updater()
    before = _state(updater)
    with pytest.raises(ModelError, match="not finite"):
        updater.probe(0.0, np.array([1e200, 2.0, 1.0]), 13.0)
    assert _state(updater) == before


def test_a_person_accepting_a_shift_has_it_taken_at_once_as_confirmed() -> None:
    """A 40 um shift a person vouches for: no flagged probe to wait on; the prediction moves to it."""
    updater = _updater(max_departure_um=10.0)
    x = np.array([10.0, 2.0, 1.0])
    (step,) = updater.probe(0.0, x, 12.0 + 40.0, accept_shift=True)
    assert step.result == "confirmed" and updater.pending is None
    assert abs(step.innovation_after_um) < 1.0  # the departure rail (10 um) gave way
    assert updater.settings.max_departure_um == 10.0  # ... for that probe only
