"""The probe update in the model's coefficients (issue 42): the prior, the bank, a cold start and a clock set back."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from compd.errors import ModelError
from compd.model.probebank import MEMBERS, UpdaterBank
from compd.model.probelearner import OutputLearner
from compd.model.proberegressors import RegressorWindow
from compd.model.probesettings import ProbeSettings, parameter_bounds
from compd.model.updateprior import BIAS, Prior, coefficient_prior

NAMES = ("T1_gain", "T2_gain", "T1_lag", BIAS)


def calibration(n: int = 2000, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Two temperatures that move together and a slow lag of the first: the calibration's unit
    responses (degC), the fitted coefficients (the lag shrunk to almost nothing), the residue."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 15.0
    heat = 10.0 * (1.0 - np.exp(-t / 7200.0))
    t1 = heat + rng.normal(0, 0.02, n)
    t2 = heat + rng.normal(0, 0.02, n)
    lag = np.convolve(t1, np.full(200, 1 / 200), mode="full")[:n]
    units = np.column_stack([t1, t2, lag])
    coefficients = np.array([3.0, 2.0, 0.01])
    residue = 0.3 * np.sin(t / 3000.0) + rng.normal(0, 0.1, n)
    return units, coefficients, residue


def test_the_coefficient_prior_is_wide_where_inputs_move_together_and_its_mean_is_the_fit() -> None:
    """The mean is the fitted coefficients; T1 - T2 is far less pinned than T1 + T2; a shrunk lag keeps room."""
    units, k, residue = calibration()
    prior = coefficient_prior(NAMES, units * k, residue, k)
    assert prior.form == "coefficients"
    np.testing.assert_array_equal(prior.mean, [3.0, 2.0, 0.01, 0.0])
    np.testing.assert_allclose(prior.units, [3.0, 2.0, 0.01, 1.0])
    p = prior.covariance
    difference = np.array([1.0, -1.0, 0.0, 0.0])
    total = np.array([1.0, 1.0, 0.0, 0.0])
    assert difference @ p @ difference > 100.0 * (total @ p @ total)
    # The lag's coefficient may move by far more than the 0.01 the fit left it.
    assert math.sqrt(p[2, 2]) > 0.1
    # The gains' posterior, in the same units, moves each coefficient in proportion to itself.
    assert prior.gains_covariance is not None
    assert math.sqrt(prior.gains_covariance[2, 2]) < 0.01


def test_the_regressors_are_contributions_per_unit_coefficient_and_reproduce_the_file() -> None:
    """x = (c / k, 1): the file's output is x' theta0, whatever the coefficients."""
    units, k, residue = calibration(200)
    prior = coefficient_prior(NAMES, units * k, residue, k)
    x = prior.regressors(units * k)
    np.testing.assert_allclose(x[:, :-1], units, rtol=1e-12)
    np.testing.assert_allclose(x @ prior.mean, (units * k).sum(axis=1), rtol=1e-12)


def test_a_term_the_calibration_shrank_grows_when_the_machine_says_so() -> None:
    """The machine's lag weighs 2 um/degC where the fit kept 0.01: the probes move it beyond the 3x a
    gain's rails allowed, and the error between the probes falls to a third."""
    units, k, residue = calibration()
    prior = coefficient_prior(NAMES, units * k, residue, k)
    learner = OutputLearner(prior, ProbeSettings.defaults(prior), RegressorWindow(0.0, math.inf))
    truth = np.array([3.0, 2.0, 2.0])
    x = prior.regressors(units * k)
    t = np.arange(len(units)) * 15.0
    learner.observe_many(t, x, np.zeros(len(t)))
    for i in range(240, len(t), 240):
        learner.probe(float(t[i]), float(units[i] @ truth))
    before = np.abs(units @ truth - (units * k).sum(axis=1))[-200:].mean()
    after = np.abs(units @ truth - learner.predict(x))[-200:].mean()
    assert learner.theta[2] > 10 * k[2]
    assert after < 0.5 * before


def test_the_members_weights_follow_how_well_each_predicted_the_probes() -> None:
    """Probes that only a moved coefficient explains shift the weight to the member that moves it."""
    units, k, residue = calibration()
    prior = coefficient_prior(NAMES, units * k, residue, k)
    bank = UpdaterBank(prior, ProbeSettings.defaults(prior))
    assert [name for name, _ in MEMBERS] == ["gains", "narrow"]
    np.testing.assert_allclose(bank.weights, [0.5, 0.5])
    x = prior.regressors(units * k)
    for i in range(240, len(units), 240):
        bank.probe(float(i), x[i], float(units[i] @ [3.0, 2.0, 2.0]))
    assert bank.weights[1] > 0.9
    np.testing.assert_allclose(bank.theta, bank.weights @ [m.theta for m in bank.members])


def test_a_coefficient_stays_within_its_rails() -> None:
    """Each coefficient within 6 prior sigma of the file's; a gain (old files) within 0..3."""
    units, k, residue = calibration(300)
    prior = coefficient_prior(NAMES, units * k, residue, k)
    low, high = parameter_bounds(prior, ProbeSettings.defaults(prior))
    sd = np.sqrt(np.diag(prior.covariance))[:-1]
    np.testing.assert_allclose(high - k, 6.0 * sd)
    gains = Prior(NAMES, np.diag([0.09, 0.09, 0.09, 1.0]), 1.0)
    low, high = parameter_bounds(gains, ProbeSettings.defaults(gains))
    assert low.tolist() == [0.0] * 3 and high.tolist() == [3.0] * 3


def learned(hours: float = 6.0) -> tuple[OutputLearner, Prior]:
    """A learner that took a probe an hour for ``hours``, the machine 5 um off the file (a shift)."""
    units, k, residue = calibration()
    prior = coefficient_prior(NAMES, units * k, residue, k)
    learner = OutputLearner(prior, ProbeSettings.defaults(prior), RegressorWindow(0.0, math.inf))
    x = prior.regressors(units * k)
    t = np.arange(len(units)) * 15.0
    learner.observe_many(t, x, np.zeros(len(t)))
    for i in range(240, min(len(t), int(hours * 240) + 1), 240):
        learner.probe(float(t[i]), float(units[i] @ (k * 1.2)) + 5.0)
    return learner, prior


def test_a_cold_start_sets_the_learned_shift_back_and_keeps_the_coefficients() -> None:
    """forget_shift: the bias is the prior's with its variance, the coefficients as learned."""
    learner, prior = learned()
    coefficients = learner.theta[:-1].copy()
    shift = learner.theta[-1]
    assert abs(shift) > 0.5
    assert learner.forget_shift() == pytest.approx(shift)
    assert learner.theta[-1] == 0.0
    np.testing.assert_allclose(learner.theta[:-1], coefficients)
    for member in learner.updater.members:
        assert member.covariance[-1, -1] == member.prior.covariance[-1, -1]
        assert not np.any(member.covariance[-1, :-1])
    units = np.array([1.0, 1.0, 1.0, 1.0])
    assert learner.adjustment_um(units) == pytest.approx(
        float(units[:-1] @ (coefficients - prior.mean[:-1]))
    )


def test_a_probe_time_in_the_future_is_set_to_now_and_a_state_far_ahead_is_refused() -> None:
    """A restored state an hour ahead (a clock set back) counts from now; a year ahead is not this machine's."""
    learner, prior = learned()
    state = json.loads(json.dumps(learner.state()))
    last = learner.last_taken_s
    assert last is not None
    now = last - 3600.0
    restored = OutputLearner.restore(prior, learner.settings, state, now_s=now, skew_s=7200.0)
    assert restored.clamped_s == pytest.approx(3600.0)
    assert restored.last_taken_s == now and restored.updater.last_time_s == now
    assert all(m.drifted_to_s == now for m in restored.updater.members)
    with pytest.raises(ModelError, match="in the future"):
        OutputLearner.restore(prior, learner.settings, state, now_s=last - 365 * 86400.0)


def test_a_state_of_one_update_is_taken_by_every_member() -> None:
    """A state saved before issue 42 (version 1, one update) restores into each member of the bank."""
    learner, prior = learned(2.0)
    state = json.loads(json.dumps(learner.state()))
    state["version"] = 1
    del state["members"]
    restored = OutputLearner.restore(prior, learner.settings, state)
    for member in restored.updater.members:
        np.testing.assert_allclose(member.theta, learner.theta)
    np.testing.assert_allclose(restored.theta, learner.theta)
