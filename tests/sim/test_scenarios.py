"""Scenarios: columns, determinism, one effect per hidden-effect run, and clear errors."""

import dataclasses

import numpy as np
import pandas as pd
import pytest

from compd.errors import CompdError
from compd.sim import (
    COLUMNS,
    SCENARIOS,
    ScenarioError,
    scenario_inputs,
    simulate_record,
    simulate_scenario,
)

HIDDEN = {
    "cutting": "cutting_power_kw",
    "feed": "feed_z_mm_per_min",
    "door": "door_open",
    "coolant": "T_coolant_degC",
}


@pytest.fixture(scope="module")
def runs() -> dict[str, pd.DataFrame]:
    return {name: simulate_scenario(name, 6, seed=11, sample_time_s=30.0) for name in SCENARIOS}


def test_every_scenario_logs_the_contract_columns(runs: dict[str, pd.DataFrame]) -> None:
    """Every scenario's frame has exactly the contract columns, in order, on a uniform time grid from 0."""
    for name, frame in runs.items():
        assert tuple(frame.columns) == COLUMNS, name
        assert frame["time_s"].iloc[0] == 0.0
        assert np.all(np.diff(frame["time_s"]) == 30.0)
        assert frame["time_s"].iloc[-1] == 6 * 3600
        assert not frame.isna().any().any()


def test_displacements_start_at_zero_within_the_noise(runs: dict[str, pd.DataFrame]) -> None:
    """A cold machine at rest is the reference: every axis starts within 5 noise std of zero."""
    for frame in runs.values():
        for axis in ("disp_x_um", "disp_y_um", "disp_z_um"):
            assert abs(frame[axis].iloc[0]) < 1.5


def test_the_same_seed_repeats_a_run_and_another_seed_changes_it() -> None:
    """Generation is deterministic given the seed; a different seed gives a different run."""
    a = simulate_scenario("door", 2, seed=5, sample_time_s=20.0)
    b = simulate_scenario("door", 2, seed=5, sample_time_s=20.0)
    c = simulate_scenario("door", 2, seed=6, sample_time_s=20.0)
    pd.testing.assert_frame_equal(a, b)
    assert not np.allclose(a["disp_z_um"], c["disp_z_um"])
    assert not np.array_equal(a["spindle_speed_rpm"], c["spindle_speed_rpm"])


def test_a_seed_gives_the_same_schedule_at_any_sample_time() -> None:
    """Schedules are drawn in continuous time: 1 s and 10 s runs of one seed agree at common instants."""
    fine = scenario_inputs("shift", 2, seed=2, sample_time_s=1.0)
    coarse = scenario_inputs("shift", 2, seed=2, sample_time_s=10.0)
    for field in ("spindle_speed_rpm", "door_open", "T_coolant_degC", "T_ambient_degC"):
        np.testing.assert_array_equal(getattr(fine, field)[::10], getattr(coarse, field))


def test_calibration_runs_the_speed_range_with_nothing_else() -> None:
    """Calibration heats at several speeds up to 12,000 rpm and cools at rest; no cutting, feed, door or coolant."""
    u = scenario_inputs("calibration", 10, seed=4, sample_time_s=60.0)
    levels = set(np.unique(u.spindle_speed_rpm))
    assert 0.0 in levels and 12000.0 in levels and len(levels) >= 5
    assert not u.cutting_power_kw.any() and not u.feed_x_mm_per_min.any()
    assert not u.feed_z_mm_per_min.any() and not u.door_open.any()
    assert np.ptp(u.T_coolant_degC) == 0.0
    assert 0.5 < np.ptp(u.T_ambient_degC) < 6.0


def test_each_hidden_effect_scenario_varies_only_its_effect() -> None:
    """cutting, feed, door and coolant each vary their own input and keep the others as in calibration."""
    for name, field in HIDDEN.items():
        u = scenario_inputs(name, 8, seed=3, sample_time_s=60.0)
        others = {
            "cutting_power_kw": u.cutting_power_kw.any(),
            "feed_z_mm_per_min": u.feed_z_mm_per_min.any() or u.feed_x_mm_per_min.any(),
            "door_open": u.door_open.any(),
            "T_coolant_degC": np.ptp(u.T_coolant_degC) > 0,
        }
        assert others.pop(field), name
        assert not any(others.values()), (name, others)


def test_shift_mixes_all_effects() -> None:
    """The shift scenario cuts, feeds, opens the door and lets the coolant drift in one run."""
    u = scenario_inputs("shift", 8, seed=3, sample_time_s=60.0)
    assert u.cutting_power_kw.max() >= 2.0 and u.feed_x_mm_per_min.max() > 1000
    assert u.door_open.any() and np.ptp(u.T_coolant_degC) >= 3.0


def test_hidden_effects_move_z_by_micrometres_but_the_base_sensors_barely() -> None:
    """Each hidden effect moves z by several um rms while changing no column sensor by more than 0.5 degC rms."""
    for name, field in HIDDEN.items():
        u = scenario_inputs(name, 8, seed=7, sample_time_s=60.0)
        without = dataclasses.replace(
            u, **{field: np.full_like(getattr(u, field), getattr(u, field)[0])}
        )
        a, b = simulate_record(u, 60.0), simulate_record(without, 60.0)
        dz = a.displacement_um[2] - b.displacement_um[2]
        assert np.sqrt(np.mean(dz**2)) > 4.0, name
        for site in ("column_front", "column_back"):
            dt = a.temperature(site) - b.temperature(site)
            assert np.sqrt(np.mean(dt**2)) < 0.5, (name, site)


def test_speed_spectrum_changes_speed_every_20_to_60_minutes() -> None:
    """The speed spectrum holds each speed for 20-60 min, stops included."""
    u = scenario_inputs("speed_spectrum", 12, seed=8, sample_time_s=60.0)
    changes = np.flatnonzero(np.diff(u.spindle_speed_rpm)) + 1
    holds_min = np.diff(changes)
    assert holds_min.min() >= 20 and holds_min.max() <= 120  # equal draws in a row merge
    assert (u.spindle_speed_rpm == 0).any()


@pytest.mark.parametrize("hours", [0.0, -1.0, float("nan"), 1e6])
def test_bad_hours_are_a_clear_error(hours: float) -> None:
    """A run length that is not a positive number of hours is refused with a CompdError."""
    with pytest.raises(ScenarioError, match="hours"):
        scenario_inputs("calibration", hours)


def test_an_unknown_scenario_lists_the_known_ones() -> None:
    """A misspelt scenario name is a CompdError naming every scenario there is."""
    with pytest.raises(CompdError, match="calibration, speed_spectrum, production, cutting"):
        simulate_scenario("calibraton", 1)


def test_a_bad_sample_time_is_refused() -> None:
    """A sample time of 0 or above 60 s is refused."""
    for ts in (0.0, 120.0):
        with pytest.raises(ScenarioError, match="sample_time_s"):
            scenario_inputs("door", 1, sample_time_s=ts)


def test_a_whole_number_sample_time_gives_float_times() -> None:
    """A sample time given as an int (10) works like 10.0, and time_s is a float column."""
    frame = simulate_scenario("coolant", 0.5, seed=1, sample_time_s=10)
    assert frame["time_s"].dtype == np.float64
    assert frame["time_s"].iloc[-1] == 1800.0
