"""The simulated driver: replay with interpolation and looping, writes kept, faults injected."""

from __future__ import annotations

import asyncio
import math
from pathlib import Path

import numpy as np
import pytest

from compd.drivers.base import Driver
from compd.drivers.registry import BUILTIN, UnknownDriverError, driver_names, load_driver_type
from compd.drivers.simulated import SimulatedDriver, SimulatedSettings
from compd.errors import DriverDisconnectedError, DriverProtocolError
from compd.service.loop.clock import VirtualClock

from .contract import ContractSetup, DriverContract


def make(tmp_path: Path, **settings) -> tuple[SimulatedDriver, VirtualClock]:
    data = tmp_path / "d.csv"
    data.write_text("time_s,a,b\n0,0,10\n10,10,10\n20,20,10\n")
    clock = VirtualClock()
    settings.setdefault("data", str(data))
    driver = SimulatedDriver(SimulatedSettings(**settings), now=clock.now, base_dir=tmp_path)
    asyncio.run(driver.open())
    return driver, clock


def read(driver: SimulatedDriver, *points: str) -> dict[str, float]:
    return asyncio.run(driver.read(points))


def test_registered_and_satisfies_the_protocol(tmp_path):
    """The simulated driver is in the registry and is a Driver."""
    assert load_driver_type("simulated") is SimulatedDriver and "simulated" in driver_names()
    assert isinstance(make(tmp_path)[0], Driver)


def test_interpolates_and_loops(tmp_path):
    """Reads interpolate linearly on the clock and wrap to the start one sample after the end."""
    driver, clock = make(tmp_path)
    values = []
    for t in (0.0, 5.0, 25.0, 30.0, 35.0):
        clock.t = t
        values.append(read(driver, "a")["a"])
    assert values == [0.0, 5.0, 20.0, 0.0, 5.0]


def test_a_read_at_any_time_is_what_a_fresh_driver_reads_then(tmp_path):
    """Forward a tick, back, past the end and across the seam: each read finds its own samples."""
    driver, clock = make(tmp_path)
    for t in (0.0, 1.0, 2.0, 12.5, 13.5, 3.0, 19.9, 20.0, 29.0, 31.0, 0.5, 64.0, 64.5, 10.0):
        clock.t = t
        fresh, fresh_clock = make(tmp_path)
        fresh_clock.t = t
        assert read(driver, "a", "b") == read(fresh, "a", "b"), t


def test_time_scale_and_start(tmp_path):
    """time_scale data seconds pass per clock second, from start_s."""
    driver, clock = make(tmp_path, time_scale=2.0, start_s=4.0, loop=False)
    clock.t = 3.0
    assert read(driver, "a")["a"] == pytest.approx(10.0)
    clock.t = 100.0
    assert read(driver, "a")["a"] == 20.0  # without loop, the last value holds


def test_bundled_data(tmp_path):
    """A bundled:NAME data file resolves through the installed package."""
    driver = SimulatedDriver(
        SimulatedSettings(data="bundled:example_spectrum.csv"), now=lambda: 0.0, base_dir=tmp_path
    )
    assert "T_spindle_degC" in driver.columns


def test_unknown_address_is_a_protocol_error(tmp_path):
    """Reading a column the file does not have raises DriverProtocolError."""
    driver, _ = make(tmp_path)
    with pytest.raises(DriverProtocolError, match="no column"):
        read(driver, "c")


def test_writes_are_kept(tmp_path):
    """Written values are kept by address and counted."""
    driver, _ = make(tmp_path)
    asyncio.run(driver.write({"x": 1.5, "y": 2.0}))
    asyncio.run(driver.write({"x": 3.0}))
    assert driver.written == {"x": 3.0, "y": 2.0} and driver.writes == 2


def test_injected_faults(tmp_path):
    """stuck, nan and value faults change one address for their duration; drop disconnects."""
    driver, clock = make(tmp_path)
    clock.t = 2.0
    driver.inject("stuck", "a", duration_s=5.0)
    driver.inject("value", "b", duration_s=3.0, value=-99.0)
    first = read(driver, "a", "b")
    clock.t = 4.0
    assert read(driver, "a", "b") == {"a": first["a"], "b": -99.0}
    clock.t = 8.0
    assert read(driver, "a", "b") == {"a": 8.0, "b": 10.0}
    driver.inject("nan", "a", duration_s=1.0)
    assert math.isnan(read(driver, "a")["a"])
    driver.inject("drop", duration_s=10.0)
    with pytest.raises(DriverDisconnectedError):
        read(driver, "a")
    clock.t = 18.0
    assert np.isfinite(read(driver, "a")["a"])


def test_scheduled_faults_from_settings(tmp_path):
    """Faults listed in the settings start at start_s clock seconds after open."""
    driver, clock = make(tmp_path, faults=[{"kind": "drop", "start_s": 5, "duration_s": 5}])
    clock.t = 6.0
    with pytest.raises(DriverDisconnectedError):
        asyncio.run(driver.write({"x": 1.0}))


class TestSimulatedContract(DriverContract):
    """The simulated driver passes the driver contract."""

    @pytest.fixture
    def setup(self, tmp_path: Path) -> ContractSetup:
        driver, _ = make(tmp_path)
        return ContractSetup(
            driver=driver,
            readable=("a", "b"),
            writable="comp_um",
            missing="nope",
            break_connection=lambda: driver.inject("drop", duration_s=60.0),
        )


def test_a_driver_type_is_imported_only_when_a_config_names_it():
    """The registry names every type without importing one; an unknown name is refused."""
    assert set(BUILTIN) <= set(driver_names())
    with pytest.raises(UnknownDriverError):
        load_driver_type("no-such-bus")
