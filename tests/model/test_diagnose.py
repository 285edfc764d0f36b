"""Diagnosis: the candidate that produced the residue ranks first, with its sign, gain and time constant."""

import numpy as np
import pytest
import scipy.signal

from compd.model.diagnose import diagnose_residue
from compd.model.lagscore import lag_bank, time_constant_bank

SAMPLE_TIME_S = 10.0
N = 8640  # 24 h at 10 s
TAU_S = 1800.0
GAIN_UM_PER_KW = -2.5


def lag(x: np.ndarray, tau_s: float) -> np.ndarray:
    pole = np.exp(-SAMPLE_TIME_S / tau_s)
    return scipy.signal.lfilter([0.0, 1.0 - pole], [1.0, -pole], x - x[0])


@pytest.fixture(scope="module")
def candidates() -> dict[str, np.ndarray]:
    """Slow, mutually correlated machine signals: speed, power (from speed and a process term), temperatures."""
    rng = np.random.default_rng(5)
    t = np.arange(N) * SAMPLE_TIME_S
    speed = np.zeros(N)
    k = 0
    while k < N:
        on, off = int(rng.integers(60, 300)), int(rng.integers(20, 100))
        speed[k : k + on] = rng.uniform(2000.0, 10000.0)
        k += on + off
    power = 1.5e-4 * speed + 2.0 * (np.sin(t / 5000.0) > 0.3) * (speed > 0)
    ambient = 20.0 + 1.5 * np.sin(2 * np.pi * t / 86_400.0)
    return {
        "spindle_speed_rpm": speed,
        "spindle_power_kw": power,
        "T_ambient_degC": ambient,
        "T_spindle_degC": ambient + lag(1e-3 * speed, 900.0),
        "walk": np.cumsum(rng.normal(0.0, 0.05, N)),
    }


@pytest.fixture(scope="module")
def diagnosis(candidates: dict):
    """The residue is GAIN * lag_TAU(spindle power) + white noise."""
    rng = np.random.default_rng(6)
    residue = GAIN_UM_PER_KW * lag(candidates["spindle_power_kw"], TAU_S) + rng.normal(0.0, 0.3, N)
    return diagnose_residue(residue, candidates, SAMPLE_TIME_S)


def test_the_causing_candidate_ranks_first_with_its_sign_gain_and_time_constant(diagnosis) -> None:
    """Power ranks first; its fitted TF has the true sign, static gain within 5 % and time constant within 10 %."""
    best = diagnosis.candidates[0]
    assert best.signal == "spindle_power_kw"
    assert best.sign == -1
    assert best.gain_um_per_unit == pytest.approx(GAIN_UM_PER_KW, rel=0.05)
    assert best.time_constant_s == pytest.approx(TAU_S, rel=0.1)
    assert best.explained_percent > 80.0
    assert best.explained_percent > diagnosis.candidates[1].explained_percent + 10.0


def test_the_causing_candidate_is_named_and_corroborated(diagnosis) -> None:
    """The residue is not white, power is the missing effect, and its cross-correlation is significant."""
    assert not diagnosis.residue_white
    assert diagnosis.missing_effect is not None
    assert diagnosis.missing_effect.signal == "spindle_power_kw"
    assert diagnosis.missing_effect.significant
    assert (
        diagnosis.missing_effect.explained_percent > diagnosis.missing_effect.chance_percent + 30.0
    )


def test_candidates_are_ordered_best_first(diagnosis) -> None:
    """Explained shares decrease down the ranking, and every candidate is scored once."""
    shares = [c.explained_percent for c in diagnosis.candidates]
    assert shares == sorted(shares, reverse=True)
    assert len({c.signal for c in diagnosis.candidates}) == 5


def test_an_independent_random_walk_is_not_significant_though_the_naive_bound_flags_it(
    diagnosis,
) -> None:
    """The walk's cross-correlation peak exceeds 2.576/sqrt(N) but not its Bartlett bound."""
    walk = next(c for c in diagnosis.candidates if c.signal == "walk")
    assert abs(walk.xcorr_peak) > diagnosis.naive_bound
    assert walk.xcorr_bound > abs(walk.xcorr_peak)
    assert not walk.significant


def test_white_residue_is_called_white_and_names_no_effect(candidates: dict) -> None:
    """A white-noise residue passes the whiteness test; no candidate is named."""
    residue = np.random.default_rng(7).normal(0.0, 0.5, N)
    diagnosis = diagnose_residue(residue, candidates, SAMPLE_TIME_S)
    assert diagnosis.residue_white
    assert diagnosis.missing_effect is None
    assert all(c.explained_percent < 5.0 for c in diagnosis.candidates)


def test_a_slow_residue_from_an_unlogged_cause_names_no_effect(candidates: dict) -> None:
    """A residue driven by a signal that is not among the candidates is not white, yet nothing is named."""
    rng = np.random.default_rng(8)
    hidden = np.cumsum(rng.normal(0.0, 1.0, N))
    residue = 0.05 * lag(hidden, 600.0) + rng.normal(0.0, 0.05, N)
    diagnosis = diagnose_residue(residue, candidates, SAMPLE_TIME_S)
    assert not diagnosis.residue_white
    assert diagnosis.missing_effect is None


def test_lag_bank_is_the_zero_order_hold_first_order_lag() -> None:
    """Each row is x(k) = p x(k-1) + (1-p) u(k-1), from rest, with p = exp(-Ts/tau)."""
    u = np.random.default_rng(9).normal(size=50)
    (row,) = lag_bank(u, np.array([30.0]), SAMPLE_TIME_S)
    p = np.exp(-SAMPLE_TIME_S / 30.0)
    x = np.zeros(50)
    for k in range(1, 50):
        x[k] = p * x[k - 1] + (1 - p) * u[k - 1]
    np.testing.assert_allclose(row, x, atol=1e-12)


def test_time_constant_bank_stays_inside_the_record() -> None:
    """Time constants run from max(60 s, 2 Ts) to min(8 h, half the record), log-spaced."""
    taus = time_constant_bank(SAMPLE_TIME_S, 4 * 3600.0)
    assert taus[0] == pytest.approx(60.0) and taus[-1] == pytest.approx(7200.0)
    assert np.allclose(np.diff(np.log(taus)), np.log(taus[1] / taus[0]))


def test_a_constant_candidate_is_refused(candidates: dict) -> None:
    """A constant signal cannot explain anything: the caller is told to leave it out."""
    with pytest.raises(ValueError, match="constant"):
        diagnose_residue(np.ones(N), {"flat": np.full(N, 3.0)}, SAMPLE_TIME_S)


def test_a_short_record_is_cut_into_fewer_blocks_of_at_least_20_samples() -> None:
    """5 blocks where the record holds them, down to 3 (64 samples); fewer is refused, saying how many."""
    from compd.model.diagnose import MIN_DIAGNOSED_SAMPLES, diagnosis_blocks

    assert [diagnosis_blocks(n) for n in (64, 72, 99, 100, 5000)] == [3, 3, 4, 5, 5]
    assert MIN_DIAGNOSED_SAMPLES == 64
    with pytest.raises(ValueError, match="63 samples are too few to cross-validate: at least 64"):
        diagnosis_blocks(63)
