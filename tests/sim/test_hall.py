"""The air-conditioned hall: only the ambient sensor reads the AC cycle and its noise."""

from __future__ import annotations

import numpy as np
import pytest

from compd.cli import main
from compd.files.data import load_data
from compd.sim import simulate_scenario
from compd.sim.hall import AirConditioning, air_conditioned


def test_ambient_reads_a_triangle_cycle_of_the_given_period_and_amplitude():
    """Without noise the disturbance is a triangle of +-amplitude repeating every period."""
    ac = AirConditioning(period_s=900.0, amplitude_degC=0.4, noise_degC=0.0)
    time_s = np.arange(0.0, 7200.0, 10.0)
    cycle = ac.ambient_disturbance_degC(time_s, seed=3)
    assert cycle.max() == pytest.approx(0.4, abs=0.01) and cycle.min() == pytest.approx(
        -0.4, abs=0.01
    )
    np.testing.assert_allclose(cycle[90:], cycle[:-90], atol=1e-12)  # 900 s = 90 samples


def test_only_the_ambient_column_changes_and_the_seed_repeats_it():
    """Every column but T_ambient_degC is the twin's; the same seed gives the same sensor reading."""
    frame = simulate_scenario("calibration", 2.0, 5, 10.0)
    hall = air_conditioned(frame, 5)
    changed = [c for c in frame.columns if not np.array_equal(frame[c], hall[c])]
    assert changed == ["T_ambient_degC"]
    np.testing.assert_array_equal(
        hall["T_ambient_degC"], air_conditioned(frame, 5)["T_ambient_degC"]
    )


def test_twin_command_writes_the_air_conditioned_hall(tmp_path):
    """``compd twin --air-conditioned`` writes the ambient sensor with the cycle on top of the plain run."""
    plain, hall = tmp_path / "plain.csv", tmp_path / "hall.csv"
    argv = ["twin", "--scenario", "calibration", "--hours", "2", "--sample-time-s", "10"]
    assert main([*argv, "--out", str(plain)]) == 0
    assert main([*argv, "--out", str(hall), "--air-conditioned"]) == 0
    difference = load_data(hall).column("T_ambient_degC") - load_data(plain).column(
        "T_ambient_degC"
    )
    assert 0.3 < np.ptp(difference) / 2 < 0.6
    np.testing.assert_array_equal(
        load_data(hall).column("disp_z_um"), load_data(plain).column("disp_z_um")
    )
