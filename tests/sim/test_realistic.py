"""Realistic twin runs: the sensor failure modes of a real machine's log, the programmes, the cut, the creep."""

import dataclasses

import numpy as np
import pandas as pd
import pytest

from compd.sim import MachineParameters
from compd.sim.realistic import (
    CALIBRATION_PROGRAMME,
    COLUMNS,
    CUT_H,
    DISPLACEMENT_COLUMNS,
    OFFSET_DEGC,
    RECORD_H,
    TEMPERATURE_COLUMNS,
    simulate_real_calibration,
    simulate_real_record,
    simulate_real_verify,
    structural_creep_um,
)

SAMPLE_S = 60.0
NEAR_DUPLICATES = (("T1", "T2"), ("T1", "T3"), ("T12", "T14"), ("T13", "T15"))
AMBIENT_ONLY = ("T6", "T7", "T10")


@pytest.fixture(scope="module")
def record() -> pd.DataFrame:
    return simulate_real_record(RECORD_H, seed=5, sample_time_s=SAMPLE_S)


def _hours(frame: pd.DataFrame) -> np.ndarray:
    return np.asarray(frame["time_s"] / 3600.0)


def _high_pass(x: np.ndarray, window: int) -> np.ndarray:
    """``x`` minus its centred moving average over ``window`` samples (ends dropped)."""
    smooth = np.convolve(x, np.ones(window) / window, mode="valid")
    half = window // 2
    return np.asarray(x[half : half + smooth.size] - smooth)


def test_the_record_logs_time_speed_sixteen_temperatures_and_three_displacements(
    record: pd.DataFrame,
) -> None:
    """A record has time_s, spindle_speed_rpm, T1..T16 and disp_x/y/z_um, on a uniform grid over 46 h."""
    assert tuple(record.columns) == COLUMNS
    assert len(TEMPERATURE_COLUMNS) == 16
    assert np.all(np.diff(record["time_s"]) == SAMPLE_S)
    assert record["time_s"].iloc[-1] == RECORD_H * 3600 == 46 * 3600
    assert not record.isna().any().any()


def test_calibration_is_four_heat_and_cool_cycles_of_rising_speed(record: pd.DataFrame) -> None:
    """Up to the cut at 32 h: 4 h at 3,000, 6,000, 9,000, 12,000 rpm, each followed by 4 h standing."""
    hours, speed = _hours(record), record["spindle_speed_rpm"].to_numpy()
    assert CUT_H == 32.0
    for cycle, rpm in enumerate((3000.0, 6000.0, 9000.0, 12000.0)):
        start = 8.0 * cycle
        assert np.all(speed[(hours >= start) & (hours < start + 4)] == rpm)
        assert np.all(speed[(hours >= start + 4) & (hours < start + 8)] == 0.0)
    assert len(CALIBRATION_PROGRAMME) == 8


def test_verify_runs_another_speed_and_a_rising_ladder(record: pd.DataFrame) -> None:
    """After the cut: a speed calibration never ran, then a ladder of at least four rising 1 h steps."""
    hours, speed = _hours(record), record["spindle_speed_rpm"].to_numpy()
    calibration_speeds = set(np.unique(speed[hours < CUT_H]))
    verify = speed[hours >= CUT_H]
    assert verify[0] not in calibration_speeds and verify[0] > 0
    levels = verify[np.flatnonzero(np.diff(verify, prepend=-1.0))]  # one per step
    running = [level for level in levels[2:] if level > 0]
    assert len(running) >= 4 and running == sorted(running)
    assert not set(running) & calibration_speeds


def test_near_duplicates_correlate_yet_read_apart_by_their_offsets(record: pd.DataFrame) -> None:
    """Sensors on one part correlate above 0.99; their difference is nearly constant, set by Pt100 offsets."""
    for a, b in NEAR_DUPLICATES:
        assert np.corrcoef(record[a], record[b])[0, 1] > 0.99, (a, b)
        difference = record[a] - record[b]
        assert difference.std() < 0.15, (a, b)
        assert abs(difference.mean()) < 2 * OFFSET_DEGC + 0.2, (a, b)


def test_the_offsets_between_near_duplicates_are_drawn_per_machine() -> None:
    """Across machines (seeds) the constant difference of a near-duplicate pair spreads by over 0.1 degC std."""
    runs = [simulate_real_calibration(4, seed=seed, sample_time_s=SAMPLE_S) for seed in range(8)]
    for a, b in NEAR_DUPLICATES:
        assert np.std([(run[a] - run[b]).mean() for run in runs]) > 0.1, (a, b)


def test_ambient_only_sensors_do_not_respond_to_the_spindle() -> None:
    """T6, T7 and T10 read the same with and without spindle heat, while the bearing sensor T9 does not."""
    base = MachineParameters()
    cold = dataclasses.replace(
        base, heat=dataclasses.replace(base.heat, k_bearing_w=0.0, k_motor0_w=0.0, k_motor1_w=0.0)
    )
    hot = simulate_real_record(16, seed=2, sample_time_s=SAMPLE_S)
    unheated = simulate_real_record(16, seed=2, sample_time_s=SAMPLE_S, params=cold)
    for column in AMBIENT_ONLY:
        np.testing.assert_array_equal(hot[column], unheated[column])
    assert (hot["T9"] - unheated["T9"]).max() > 2.0


def test_ambient_swings_by_degrees_over_the_record(record: pd.DataFrame) -> None:
    """The shop floor swings by 1.5-6 degC peak to peak over 46 h (day and night, HVAC)."""
    for column in AMBIENT_ONLY:
        assert 1.5 < np.ptp(record[column]) < 6.0, column


def test_one_sensor_is_noisy_with_spikes(record: pd.DataFrame) -> None:
    """T16 jumps by more than 0.5 degC at least 20 times in 46 h and is over 5x noisier than T1."""
    assert (record["T16"].diff() > 0.5).sum() >= 20
    assert record["T16"].diff().std() > 5 * record["T1"].diff().std()


def test_the_chiller_cycle_shows_in_its_sensor_and_in_z(record: pd.DataFrame) -> None:
    """T4 cycles by about +-1 degC every 12-32 min, and z follows the cycle within 10 min (high-passed)."""
    t4 = _high_pass(record["T4"].to_numpy(), 31)
    z = _high_pass(record["disp_z_um"].to_numpy(), 31)
    assert 0.3 < t4.std() < 1.0
    spectrum = np.abs(np.fft.rfft(t4))
    period_min = 1.0 / np.fft.rfftfreq(t4.size, SAMPLE_S / 60.0)[1 + np.argmax(spectrum[1:])]
    assert 12.0 <= period_min <= 32.0
    delays = range(int(600 / SAMPLE_S) + 1)
    following = [abs(np.corrcoef(t4[: t4.size - k], z[k:])[0, 1]) for k in delays]
    assert max(following) > 0.3


def test_readings_are_quantised(record: pd.DataFrame) -> None:
    """Temperatures are logged in steps of 0.01 degC and displacements in 0.01 um."""
    for column in (*TEMPERATURE_COLUMNS, *DISPLACEMENT_COLUMNS):
        steps = record[column].to_numpy() * 100
        np.testing.assert_allclose(steps, np.round(steps), atol=1e-6, err_msg=column)


def test_displacements_start_at_zero(record: pd.DataFrame) -> None:
    """The record starts cold at rest: each displacement starts within 0.5 um of zero."""
    for column in DISPLACEMENT_COLUMNS:
        assert abs(record[column].iloc[0]) < 0.5


def test_the_creep_is_a_fraction_of_a_micrometre_per_hour_and_goes_on() -> None:
    """The unmodelled creep moves every axis by under 0.5 um/h (z the most) and still moves after the cut."""
    time_s = np.arange(0, RECORD_H * 3600 + 1, 60.0)
    for seed in range(5):
        creep = structural_creep_um(np.random.default_rng(seed), time_s)
        assert creep.shape == (3, time_s.size)
        rate = np.abs(creep[:, -1] - creep[:, 0]) / RECORD_H
        assert np.all(rate < 0.5)
        assert rate[2] > 0.05
        after_cut = creep[:, time_s >= CUT_H * 3600]
        assert np.all(np.ptp(after_cut, axis=1) > 0.5)


def test_calibration_and_verify_are_the_two_parts_of_the_record(record: pd.DataFrame) -> None:
    """real_calibration is the record up to the cut; real_verify is the rest, time from 0, displacements re-zeroed."""
    calibration = simulate_real_calibration(CUT_H, seed=5, sample_time_s=SAMPLE_S)
    verify = simulate_real_verify(RECORD_H - CUT_H, seed=5, sample_time_s=SAMPLE_S)
    head = record[record["time_s"] <= CUT_H * 3600].reset_index(drop=True)
    tail = record[record["time_s"] >= CUT_H * 3600].reset_index(drop=True)
    pd.testing.assert_frame_equal(calibration, head)
    assert verify["time_s"].iloc[0] == 0.0 and len(verify) == len(tail)
    pd.testing.assert_frame_equal(
        verify[list(TEMPERATURE_COLUMNS)], tail[list(TEMPERATURE_COLUMNS)]
    )
    for column in DISPLACEMENT_COLUMNS:
        assert verify[column].iloc[0] == 0.0
        np.testing.assert_allclose(verify[column], tail[column] - tail[column].iloc[0], atol=0.011)


def test_the_same_seed_repeats_a_run_and_another_seed_changes_it() -> None:
    """Generation is deterministic given the seed; another seed draws other offsets, ambient and creep."""
    a = simulate_real_calibration(8, seed=1, sample_time_s=SAMPLE_S)
    b = simulate_real_calibration(8, seed=1, sample_time_s=SAMPLE_S)
    c = simulate_real_calibration(8, seed=2, sample_time_s=SAMPLE_S)
    pd.testing.assert_frame_equal(a, b)
    assert not np.allclose(a["T6"], c["T6"])
    assert not np.allclose(a["disp_z_um"], c["disp_z_um"])
    pd.testing.assert_series_equal(a["spindle_speed_rpm"], c["spindle_speed_rpm"])
