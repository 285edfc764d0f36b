"""What the logger records: Pt100 lag, class-A offsets and noise; displacement and power noise."""

import numpy as np
import pytest

from compd.sim.machine import MachineParameters
from compd.sim.sensors import (
    COLUMNS,
    DISPLACEMENT_NOISE_UM,
    PT100_NOISE_DEGC,
    TEMPERATURE_SENSORS,
    SensorBank,
    SensorSet,
    class_a_tolerance_degc,
    lag,
    read_displacements,
    read_temperatures,
    reported_power_kw,
)
from compd.sim.thermal import MachineInputs, MachineTwin


def test_lag_reaches_63_percent_after_one_time_constant() -> None:
    """A first-order sensor lag of 30 s shows 1 - 1/e of a step after 30 s, exactly at any sample time."""
    for ts in (1.0, 10.0):
        step = np.r_[0.0, np.ones(int(120 / ts))]
        y = lag(step, 30.0, ts)
        assert y[0] == 0.0
        assert y[int(30 / ts)] == pytest.approx(1 - np.exp(-1), abs=1e-12)


def test_temperature_noise_and_offsets_are_pt100_class_a() -> None:
    """Readings of a constant 20 degC scatter by 0.015 degC around a fixed offset inside ±(0.15 + 0.002|T|)."""
    rng = np.random.default_rng(3)
    sensors = SensorSet.draw(rng)
    true = {name: np.full(20000, 20.0) for name in TEMPERATURE_SENSORS}
    readings = read_temperatures(true, sensors, 1.0, rng)
    for name, values in readings.items():
        assert abs(values.mean() - 20.0) <= class_a_tolerance_degc(20.0)
        assert values.mean() - 20.0 == pytest.approx(sensors.offset_degc[name], abs=0.001)
        assert values.std() == pytest.approx(PT100_NOISE_DEGC, rel=0.05)


def test_sensor_lags_are_tens_of_seconds() -> None:
    """Each temperature sensor gets its own lag between 20 and 60 s."""
    lags = SensorSet.draw(np.random.default_rng(0)).lag_s.values()
    assert all(20.0 <= t <= 60.0 for t in lags)
    assert len(set(lags)) == len(TEMPERATURE_SENSORS)


def test_displacement_noise_is_a_third_of_a_micrometre() -> None:
    """Displacement readings carry white noise of 0.3 um std on each axis."""
    noisy = read_displacements(np.zeros((3, 50000)), np.random.default_rng(4))
    for values in noisy.values():
        assert values.std() == pytest.approx(DISPLACEMENT_NOISE_UM, rel=0.03)


def test_power_is_zero_at_standstill_and_noisy_while_turning() -> None:
    """The drive reports 0 kW when stopped and no-load plus cutting power, with noise, when turning."""
    speed = np.r_[np.zeros(1000), np.full(1000, 6000.0)]
    cut = np.r_[np.zeros(1000), np.full(1000, 4.0)]
    p = reported_power_kw(MachineParameters(), speed, cut, np.random.default_rng(5))
    assert np.all(p[:1000] == 0.0)
    assert 4.0 < p[1000:].mean() < 4.5
    assert 0.005 < p[1000:].std() < 0.02


def test_live_sensor_bank_reads_like_a_logged_record() -> None:
    """SensorBank on a stepped twin gives the lagged true temperature plus offset, off only by the Pt100 noise."""
    ts = 10.0
    rng = np.random.default_rng(6)
    sensors = SensorSet.draw(rng)
    bank = SensorBank(sensors, ts, rng)
    twin = MachineTwin(MachineInputs(20.0, 20.0), sample_time_s=ts)
    hot = MachineInputs(20.0, 20.0, spindle_speed_rpm=10000.0)
    rows, true = [bank.read(twin.state, hot)], [twin.state.temperature("bearings")]
    for _ in range(1000):
        state = twin.step(hot)
        rows.append(bank.read(state, hot))
        true.append(state.temperature("bearings"))
    assert list(rows[-1]) == list(COLUMNS[1:])
    expected = lag(np.array(true), sensors.lag_s["T_spindle_degC"], ts)
    error = (
        np.array([r["T_spindle_degC"] for r in rows])
        - expected
        - sensors.offset_degc["T_spindle_degC"]
    )
    assert abs(error.mean()) < 0.003
    assert error.std() == pytest.approx(PT100_NOISE_DEGC, rel=0.15)
    assert rows[-1]["disp_z_um"] < -20.0
