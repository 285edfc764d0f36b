"""An external offset outside the clamp held by LinuxCNC is replaced, never followed (s32 counts over HAL).

The same judgement as on a Modbus register (:mod:`tests.service.test_readback_clamp`),
through another driver: Debian's LinuxCNC running headless from a simulated
mill (:mod:`tests.drivers.linuxcnc_machine`), Z's external offset in counts of 0.1 um.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from compd.drivers.linuxcnc import LinuxCncDriver, LinuxCncSettings
from compd.service.daemon import Service
from compd.service.loop.clock import RealClock
from compd.service.loop.compensator import TickRecord
from compd.service.loop.safety import Level

from ..service.daemon_setup import write_config
from . import linuxcnc_machine
from .contract import run_calls
from .linuxcnc_machine import Machine


@pytest.fixture(scope="module")
def machine(tmp_path_factory) -> Iterator[Machine]:
    """One headless LinuxCNC for the module (HAL allows one per host)."""
    running = linuxcnc_machine.start(tmp_path_factory.mktemp("linuxcnc"))
    yield running
    running.stop()


def driver(machine: Machine, component: str) -> LinuxCncDriver:
    settings = LinuxCncSettings(component=component, ini_file=str(machine.folder / "sim.ini"))
    return LinuxCncDriver(settings, now=time.monotonic, base_dir=Path())


def test_an_offset_outside_the_clamp_held_by_linuxcnc_is_replaced(tmp_path, machine):
    """axis.z at 5000 counts (500 um, clamp 150 um) at start: compd writes 0, never 4990 counts, and flags it."""
    run_calls(driver(machine, "setup"), ("write", {"axis.z": 5000.0}))
    config = write_config(tmp_path, machine.service_config(max_offset_um=150))
    records: list[TickRecord] = []
    # Real time, 20x fast: HAL is real I/O, which a virtual clock would outrun.
    service = Service(config, clock=RealClock(20.0), control=False, background_saves=False)
    service.subscribe(records.append)
    try:
        asyncio.run(service.run(duration_s=20.0))
    finally:
        run_calls(driver(machine, "clean"), ("write", {"axis.z": 0.0}))
    read = [r for r in records if math.isfinite(r.readback_um["Y"])]
    assert read[0].readback_um["Y"] == 500.0
    assert read[0].acknowledged_um["Y"] == 0.0  # the last valid offset: none yet, so 0
    assert read[0].status & 0b11 == Level.FAULTED
    acknowledged = [r.acknowledged_um["Y"] for r in records]
    assert all(abs(a) <= 150.0 for a in acknowledged if math.isfinite(a))
    assert service.compensator.counters.offsets_out_of_clamp == 1
