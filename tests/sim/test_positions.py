"""The feed_positions twin run: the feed run measured at moving X/Z positions, with a growing ball screw."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from compd.sim import COLUMNS, scenario_inputs, simulate_record, simulate_scenario
from compd.sim.machine import ALPHA_STEEL_PER_K
from compd.sim.positions import (
    POSITION_COLUMNS,
    X_STOPS_MM,
    Z_STOPS_MM,
    position_schedule,
    simulate_feed_positions,
)

HOURS, SEED, SAMPLE_S = 6, 4, 30.0


@pytest.fixture(scope="module")
def runs() -> tuple[pd.DataFrame, pd.DataFrame]:
    return (
        simulate_feed_positions(HOURS, seed=SEED, sample_time_s=SAMPLE_S),
        simulate_scenario("feed", HOURS, seed=SEED, sample_time_s=SAMPLE_S),
    )


def test_the_run_adds_position_columns_and_keeps_the_feed_runs_others(
    runs: tuple[pd.DataFrame, pd.DataFrame],
) -> None:
    """Contract columns first, then positions and screw temperatures; all but disp_x/disp_z equal the feed run."""
    positions, feed = runs
    assert tuple(positions.columns) == (*COLUMNS, *POSITION_COLUMNS)
    unchanged = [c for c in COLUMNS if c not in ("disp_x_um", "disp_z_um")]
    pd.testing.assert_frame_equal(positions[unchanged], feed[unchanged])
    assert set(np.unique(positions.X_position_mm)) <= set(X_STOPS_MM)
    assert set(np.unique(positions.Z_position_mm)) <= set(Z_STOPS_MM)
    assert np.unique(positions.X_position_mm).size >= 4


def test_the_x_error_grows_with_the_distance_from_the_fixed_bearing(
    runs: tuple[pd.DataFrame, pd.DataFrame],
) -> None:
    """disp_x differs from the feed run's by alpha * (X - 500 mm) * the X screw's temperature rise."""
    positions, feed = runs
    record = simulate_record(scenario_inputs("feed", HOURS, SEED, SAMPLE_S), SAMPLE_S)
    rise = record.temperature("nut_x") - record.temperature("nut_x")[0]
    expected = ALPHA_STEEL_PER_K * 1e3 * (positions.X_position_mm - 500.0) * rise
    np.testing.assert_allclose(positions.disp_x_um - feed.disp_x_um, expected, atol=1e-9)
    assert rise.max() > 2.0  # the screw does heat: several um of slope over the travel
    # the screw sensor sees that rise (lag, offset and noise aside)
    sensed = positions.T_x_screw_degC - positions.T_x_screw_degC.iloc[0]
    assert np.corrcoef(sensed, rise)[0, 1] > 0.99


def test_a_seed_gives_the_same_positions_at_any_sample_time() -> None:
    """Positions are drawn in continuous time: 10 s and 30 s schedules of one seed agree at common instants."""
    fine_x, fine_z = position_schedule(3, seed=9, sample_time_s=10.0)
    coarse_x, coarse_z = position_schedule(3, seed=9, sample_time_s=30.0)
    np.testing.assert_array_equal(fine_x[::3], coarse_x)
    np.testing.assert_array_equal(fine_z[::3], coarse_z)
