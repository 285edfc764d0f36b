"""Failing windows: the residue cut into fixed windows, those above tolerance, conditions and calibration ranges."""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from compd.model.windows import failing_windows, window_count

SAMPLE_TIME_S = 10.0


@pytest.fixture(scope="module")
def record() -> dict[str, np.ndarray]:
    """4 h at 10 s: small noise, a 5 um error from 1:00 to 1:30, spindle power pushed to 6 kW then."""
    rng = np.random.default_rng(3)
    t = np.arange(0.0, 4 * 3600.0, SAMPLE_TIME_S)
    residue = rng.normal(0.0, 0.2, len(t))
    injected = (t >= 3600.0) & (t < 5400.0)
    residue[injected] += 5.0
    power = np.where(injected, 6.0, 1.0 + rng.uniform(0.0, 1.0, len(t)))
    speed = rng.uniform(1000.0, 8000.0, len(t))
    return {"time_s": t, "residue_um": residue, "spindle_power_kw": power, "speed_rpm": speed}


def test_windows_are_found_exactly_where_the_error_was_injected(record: dict) -> None:
    """The two 15-min windows covering the injected error fail, and no other."""
    windows = failing_windows(record["time_s"], record["residue_um"], tolerance_um=1.0)
    assert [(w.start_s, w.end_s) for w in windows] == [(3600.0, 4500.0), (4500.0, 5400.0)]
    for w in windows:
        assert w.rms_um == pytest.approx(5.0, abs=0.1)


def test_window_rms_is_the_rms_of_its_samples(record: dict) -> None:
    """Each failing window's rms_um is sqrt(mean(residue^2)) over the samples in [start, end)."""
    t, residue = record["time_s"], record["residue_um"]
    for w in failing_windows(t, residue, tolerance_um=1.0, window_s=600.0):
        inside = (t >= w.start_s) & (t < w.end_s)
        assert_allclose(w.rms_um, np.sqrt(np.mean(residue[inside] ** 2)), rtol=1e-12)


def test_conditions_are_window_means_and_out_of_range_signals_are_named(record: dict) -> None:
    """Conditions are averaged per window; only the signal that left its calibration range is named."""
    windows = failing_windows(
        record["time_s"],
        record["residue_um"],
        tolerance_um=1.0,
        conditions={
            "spindle_power_kw": record["spindle_power_kw"],
            "speed_rpm": record["speed_rpm"],
        },
        ranges={"spindle_power_kw": (0.0, 3.0), "speed_rpm": (0.0, 12000.0)},
    )
    assert len(windows) == 2
    for w in windows:
        assert w.conditions["spindle_power_kw"] == pytest.approx(6.0)
        assert 1000.0 < w.conditions["speed_rpm"] < 8000.0
        assert w.outside_calibration == ("spindle_power_kw",)


def test_signals_without_a_calibration_range_are_not_judged(record: dict) -> None:
    """A condition with no range is averaged but never named outside calibration."""
    windows = failing_windows(
        record["time_s"],
        record["residue_um"],
        tolerance_um=1.0,
        conditions={"spindle_power_kw": record["spindle_power_kw"]},
    )
    assert windows and all(w.outside_calibration == () for w in windows)


def test_a_shorter_last_window_ends_at_the_last_sample() -> None:
    """A record that is not a whole number of windows ends with a shorter window, closed at the last sample."""
    t = np.arange(0.0, 1000.0, SAMPLE_TIME_S)  # 990 s: one full 900-s window and 90 s
    residue = np.where(t >= 900.0, 3.0, 0.0)
    (window,) = failing_windows(t, residue, tolerance_um=1.0, window_s=900.0)
    assert (window.start_s, window.end_s, window.rms_um) == (900.0, 990.0, 3.0)


def test_nothing_fails_below_the_tolerance(record: dict) -> None:
    """A tolerance above every window's RMS gives an empty list."""
    assert failing_windows(record["time_s"], record["residue_um"], tolerance_um=10.0) == []


@pytest.mark.parametrize(("tolerance_um", "window_s"), [(0.0, 900.0), (1.0, 0.0), (-1.0, 900.0)])
def test_non_positive_tolerance_or_window_is_refused(
    record: dict, tolerance_um: float, window_s: float
) -> None:
    """Tolerance and window length must be positive."""
    with pytest.raises(ValueError, match="must be > 0"):
        failing_windows(
            record["time_s"], record["residue_um"], tolerance_um=tolerance_um, window_s=window_s
        )


def test_sensor_noise_beyond_a_narrow_range_is_not_outside_calibration(record: dict) -> None:
    """A constant signal whose noise pokes past its noise-wide calibration range stays inside: its mean is judged."""
    rng = np.random.default_rng(4)
    coolant = 21.5 + rng.normal(0.0, 0.03, len(record["time_s"]))
    windows = failing_windows(
        record["time_s"],
        record["residue_um"],
        tolerance_um=1.0,
        conditions={"T_coolant_degC": coolant},
        ranges={"T_coolant_degC": (21.45, 21.55)},  # narrower than the noise
    )
    assert windows and all(w.outside_calibration == () for w in windows)


def test_a_last_window_of_zero_length_is_neither_judged_nor_counted() -> None:
    """16 h at 1 Hz ends with a lone sample at 16:00: 64 windows of 15 min, none of them [16:00, 16:00]."""
    t = np.arange(0.0, 16 * 3600.0 + 1.0, 1.0)  # 57,601 samples, the last one at exactly 16:00
    residue = np.full(len(t), 3.0)
    windows = failing_windows(t, residue, tolerance_um=1.0, window_s=900.0)
    assert len(windows) == 64 == window_count(t, 900.0)
    assert all(w.end_s > w.start_s for w in windows)
    assert windows[-1].start_s == 15.75 * 3600.0


def test_window_count_counts_a_shorter_last_window_and_agrees_with_the_windows() -> None:
    """A record of 990 s has two windows of 900 s (the second 90 s long); one of 900 s has one."""
    assert window_count(np.arange(0.0, 1000.0, SAMPLE_TIME_S), 900.0) == 2
    assert window_count(np.arange(0.0, 910.0, SAMPLE_TIME_S), 900.0) == 1
    assert window_count(np.array([5.0]), 900.0) == 0
