"""The drift CUSUM: a lasting departure beyond the allowance alarms after h / (a - k) hours, a smaller one never."""

from __future__ import annotations

import math

import numpy as np
import pytest

from compd.model.drift import CusumSettings, DriftCusum, smallest_step_sigma


def hours_to_alarm(departure: float, settings: CusumSettings, period_s: float = 10.0) -> float:
    cusum = DriftCusum(2, period_s, settings)
    for k in range(1, 100_000):
        _, alarmed = cusum.step(np.array([departure, math.nan]))
        assert not alarmed[1], "a departure not judged (NaN) never alarms"
        if alarmed[0]:
            return k * period_s / 3600.0
    return math.inf


def test_a_step_above_the_allowance_alarms_after_h_over_its_excess() -> None:
    settings = CusumSettings(k_sigma=3.0, h_sigma_h=0.25)
    assert hours_to_alarm(5.0, settings) == pytest.approx(0.25 / 2.0, abs=10 / 3600)
    assert hours_to_alarm(-5.0, settings) == pytest.approx(0.25 / 2.0, abs=10 / 3600)
    assert hours_to_alarm(2.9, settings) == math.inf


def test_the_first_departure_is_where_the_statistic_left_zero_and_a_reset_clears_it() -> None:
    cusum = DriftCusum(1, 60.0)
    departed, _ = cusum.step(np.array([1.0]))
    assert not departed[0] and cusum.statistic[0] == 0.0
    departed, _ = cusum.step(np.array([4.0]))
    assert departed[0] and cusum.statistic[0] > 0.0
    cusum.reset()
    assert cusum.statistic[0] == 0.0


def test_the_smallest_step_a_following_reference_lets_through_matches_a_simulation() -> None:
    """Against an hour-long reference a step decays as a exp(-t / 1 h): summed, it must reach h."""
    settings = CusumSettings()
    a = smallest_step_sigma(settings)
    assert a == pytest.approx(4.4, abs=0.05)

    def alarms(step: float) -> bool:
        cusum = DriftCusum(1, 10.0, settings)
        decay = math.exp(-10.0 / 3600.0)
        g = step
        for _ in range(6 * 360):
            _, alarmed = cusum.step(np.array([g]))
            if alarmed[0]:
                return True
            g *= decay
        return False

    assert alarms(a * 1.02) and not alarms(a * 0.98)
