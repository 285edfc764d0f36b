"""The LinuxCNC driver against Debian's LinuxCNC (uspace) running headless from a simulated mill.

The offset compd writes must reach the joint position, ramped by LinuxCNC's
own rate limit (``OFFSET_AV_RATIO`` x ``MAX_VELOCITY``), measured on the
machine's servo-thread clock so that a busy machine cannot fail it.
"""

from __future__ import annotations

import asyncio
import itertools
import os
import signal
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml

from compd.drivers.linuxcnc import LinuxCncDriver, LinuxCncSettings
from compd.drivers.registry import load_driver_type
from compd.errors import ConfigFileError, DriverDisconnectedError, DriverProtocolError
from compd.service.config.loading import load_config
from compd.service.daemon import Service
from compd.service.loop.clock import RealClock
from compd.service.loop.compensator import TickRecord

from ..service.daemon_setup import write_config
from . import linuxcnc_machine
from .contract import ContractSetup, DriverContract, run_calls
from .linuxcnc_machine import MAX_VELOCITY_MM_PER_S, OFFSET_AV_RATIO, Machine

EXAMPLE = Path(__file__).parents[2] / "config" / "compd.example.yaml"
_names = (f"t{i:04d}" for i in itertools.count())


@pytest.fixture(scope="module")
def machine(tmp_path_factory) -> Iterator[Machine]:
    """One headless LinuxCNC for the module (HAL allows one per host)."""
    running = linuxcnc_machine.start(tmp_path_factory.mktemp("linuxcnc"))
    yield running
    running.stop()


def make_driver(machine: Machine | None = None, **settings) -> LinuxCncDriver:
    settings.setdefault("component", next(_names))
    if machine is not None:
        settings.setdefault("ini_file", str(machine.folder / "sim.ini"))
    return LinuxCncDriver(LinuxCncSettings(**settings), now=time.monotonic, base_dir=Path())


def test_registered():
    """The driver is registered as 'linuxcnc'."""
    assert load_driver_type("linuxcnc") is LinuxCncDriver


def test_addresses_are_checked_at_config_time():
    """Offsets go only to axis.L (an s32 count); a read address must be a HAL name."""
    LinuxCncDriver.validate_address("axis.z", writable=True)
    LinuxCncDriver.validate_address("spindle.0.speed-out", writable=False)
    for bad in ("axis.q", "joint.2.pos-cmd", "axis.z.eoffset-counts"):
        with pytest.raises(ValueError, match="axis"):
            LinuxCncDriver.validate_address(bad, writable=True)
    with pytest.raises(ValueError, match="HAL name"):
        LinuxCncDriver.validate_address("T spindle", writable=False)
    settings = LinuxCncSettings()
    assert LinuxCncDriver.raw_range("axis.z", settings) == (-(2**31), 2**31 - 1)
    assert LinuxCncDriver.reads_back(settings)


def test_the_commented_example_config_is_valid(tmp_path):
    """The commented-out LinuxCNC blocks of config/compd.example.yaml pass check-config once uncommented."""
    text = EXAMPLE.read_text()

    def uncomment(start: str, end: str) -> dict:
        block = text[text.index(start) : text.index(end)]
        return yaml.safe_load("\n".join(line.replace("# ", "", 1) for line in block.splitlines()))

    doc = yaml.safe_load(text)
    doc["drivers"].update(uncomment("  # mill:", "  # LinuxCNC addresses"))
    doc["outputs"].update(uncomment("  # Z_mill:", "# Written beside"))
    assert doc["drivers"]["mill"]["type"] == "linuxcnc"
    # The machine's INI, here: check-config reads it for the axes' OFFSET_AV_RATIO.
    ini = tmp_path / "mill.ini"
    ini.write_text("[AXIS_Z]\nOFFSET_AV_RATIO = 0.1\n")
    doc["drivers"]["mill"]["settings"]["ini_file"] = str(ini)
    path = tmp_path / "compd.yaml"
    path.write_text(yaml.safe_dump(doc))
    load_config(path)
    doc["outputs"]["Z_mill"]["address"] = "joint.2.pos-cmd"
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(ConfigFileError, match=r"axis\.x \.\. axis\.w"):
        load_config(path)


def test_a_python_without_hal_is_a_disconnect_naming_it():
    """A ``python`` lacking LinuxCNC's hal module fails open as a disconnect that quotes the helper's error."""
    driver = make_driver(python=sys.executable)  # compd's own Python: no hal module
    with pytest.raises(DriverDisconnectedError, match="No module named 'hal'"):
        run_calls(driver, ("read", ["spindle-speed"]))


def test_reads_hal_signals_and_pins(machine):
    """A signal set with halcmd and the spindle speed an MDI M3 commands are read through the component's pins."""
    machine.halcmd("sets", "T-spindle-degC", "23.5")
    machine.mdi("M3 S1200")
    driver = make_driver(machine, component="reads")
    (values,) = run_calls(driver, ("read", ["T-spindle-degC", "spindle.0.speed-out"]))
    assert values == {"T-spindle-degC": 23.5, "spindle.0.speed-out": 1200.0}
    # The component's pins are in HAL, linked like any other (here: while open).
    machine.mdi("M5")


def test_unknown_names_are_protocol_errors(machine):
    """A HAL name LinuxCNC lacks, an input pin, or a write to a non-axis raise DriverProtocolError naming it."""
    driver = make_driver(machine)
    for call, match in (
        (("read", ["no-such-signal"]), "no HAL signal or pin named 'no-such-signal'"),
        (("read", ["axis.z.eoffset-enable"]), "is an input pin"),
        (("write", {"joint.2.pos-cmd": 1.0}), "not an axis"),
    ):
        with pytest.raises(DriverProtocolError, match=match):
            run_calls(driver, call)


def test_an_axis_without_offset_av_ratio_is_refused(machine):
    """Writing to X, whose [AXIS_X] has no OFFSET_AV_RATIO (LinuxCNC would ignore it), is refused with the fix."""
    with pytest.raises(DriverProtocolError, match=r"\[AXIS_X\]OFFSET_AV_RATIO"):
        run_calls(make_driver(machine), ("write", {"axis.x": 10.0}))


def test_offset_reaches_the_joint_ramped_by_offset_av_ratio(machine):
    """A 0.5 mm offset reaches joint 2 as a ramp no faster than OFFSET_AV_RATIO x MAX_VELOCITY (machine time)."""
    offset_um, count_um = 500.0, 0.1
    limit_mm_per_s = OFFSET_AV_RATIO * MAX_VELOCITY_MM_PER_S
    points = ["machine-time-s", "joint.2.pos-cmd", "axis.z"]

    async def scenario() -> list[dict[str, float]]:
        driver = make_driver(machine, count_um=count_um)
        await driver.open()
        try:
            start = await driver.read(points)
            samples = [start]
            await driver.write({"axis.z": start["axis.z"] + offset_um / count_um})
            target = start["joint.2.pos-cmd"] + offset_um / 1000
            deadline = time.monotonic() + 30  # a hang guard; the assertions use machine time
            while time.monotonic() < deadline:
                samples.append(await driver.read(points))
                if abs(samples[-1]["joint.2.pos-cmd"] - target) < 1e-9:
                    break
                await asyncio.sleep(0.02)
            await driver.write({"axis.z": start["axis.z"]})  # leave Z where it was
            return samples
        finally:
            await driver.close()

    samples = asyncio.run(scenario())
    z0, z1 = samples[0]["joint.2.pos-cmd"], samples[-1]["joint.2.pos-cmd"]
    assert z1 - z0 == pytest.approx(offset_um / 1000, abs=1e-9)
    assert samples[-1]["axis.z"] - samples[0]["axis.z"] == offset_um / count_um  # read back
    # A ramp, not a step: samples strictly between start and target.
    between = [s for s in samples if z0 + 1e-6 < s["joint.2.pos-cmd"] < z1 - 1e-6]
    assert len(between) >= 3
    # Reaching it takes at least distance / (ratio x MAX_VELOCITY) of machine time...
    moving = [s for s in samples if s["joint.2.pos-cmd"] > z0 + 1e-9]
    last_at_start = samples[samples.index(moving[0]) - 1]["machine-time-s"]
    ramp_s = moving[-1]["machine-time-s"] - last_at_start
    assert ramp_s >= 0.99 * (offset_um / 1000) / limit_mm_per_s
    # ... and no stretch of it (>= 0.1 s, so a servo period of skew is 1 %) is faster.
    for a, b in itertools.combinations(between, 2):
        dt = b["machine-time-s"] - a["machine-time-s"]
        if dt >= 0.1:
            speed = (b["joint.2.pos-cmd"] - a["joint.2.pos-cmd"]) / dt
            assert speed <= 1.02 * limit_mm_per_s
    print(
        f"offset {offset_um} um: joint 2 {z0:.6f} -> {z1:.6f} mm in {ramp_s:.3f} s machine time "
        f"(at least {offset_um / 1000 / limit_mm_per_s:.3f} s at {limit_mm_per_s} mm/s), "
        f"{len(between)} samples mid-ramp"
    )


def test_a_new_component_picks_up_the_offset_linuxcnc_holds(machine):
    """After compd restarts, axis.z reads back the counts still applied: reconnecting never steps the offset."""
    first, second = make_driver(machine, component="keep"), make_driver(machine, component="keep")
    run_calls(first, ("write", {"axis.z": 1234.0}))
    (held,) = run_calls(second, ("read", ["axis.z"]))
    run_calls(second, ("write", {"axis.z": 0.0}))
    assert held == {"axis.z": 1234.0}


def test_service_compensates_through_linuxcnc(tmp_path, machine):
    """The daemon reads HAL (spindle speed, a warming spindle) and its offset, in 0.1 um counts, reaches joint 2."""
    machine.mdi("M3 S3000")
    machine.halcmd("sets", "T-spindle-degC", "25")
    # max_jump: the test steps the temperature, no spike.
    config = write_config(
        tmp_path,
        machine.service_config(
            # A HAL pin set by halcmd reads exactly its value: no sensor noise, so no stuck check.
            temperature_checks={"max_jump": 20, "stuck_s": None}
        ),
    )
    records: list[TickRecord] = []
    # Real time, 20x fast: HAL is real I/O, which a virtual clock would outrun.
    service = Service(config, clock=RealClock(20.0), control=False, background_saves=False)

    def on_tick(record: TickRecord) -> None:
        records.append(record)
        if len(records) == 5:  # the spindle warms by 10 K, set on HAL as a sensor would
            threading.Thread(target=machine.halcmd, args=("sets", "T-spindle-degC", "35")).start()

    service.subscribe(on_tick)
    try:
        asyncio.run(service.run(duration_s=300.0))
        (held,) = run_calls(make_driver(machine), ("read", ["axis.z", "joint.2.pos-cmd"]))
    finally:
        run_calls(make_driver(machine), ("write", {"axis.z": 0.0}))
        machine.mdi("M5")
    last = records[-1]
    assert len(records) >= 100 and all(r.written for r in records[1:])
    assert (last.values["T_spindle_degC"], last.values["spindle_speed_rpm"]) == (35.0, 3000.0)
    assert set(last.health.values()) == {0}  # every signal ok (Health.OK)
    assert abs(last.offsets_um["Y"]) >= 0.5  # the model moved the axis (1.4 um here)
    assert held["axis.z"] == round(last.offsets_um["Y"] * 10)
    assert held["joint.2.pos-cmd"] == pytest.approx(held["axis.z"] * 1e-4, abs=1e-9)
    assert service.compensator.counters.offset_mismatches == 0  # it read back what it wrote
    print(
        f"service: Y {last.offsets_um['Y']:.1f} um -> joint 2 at {held['joint.2.pos-cmd']:.6f} mm"
    )


class TestLinuxCncContract(DriverContract):
    """The LinuxCNC driver passes the driver contract; the cut link is the helper process ending."""

    @pytest.fixture
    def setup(self, machine) -> Iterator[ContractSetup]:
        driver = make_driver(machine)

        def cut() -> None:
            assert driver.helper_pid is not None
            os.kill(driver.helper_pid, signal.SIGTERM)  # what `halcmd unload` does

        yield ContractSetup(
            driver=driver,
            readable=("T-spindle-degC", "spindle.0.speed-out", "axis.z"),
            writable="axis.z",
            missing="no-such-signal",
            break_connection=cut,
        )
        run_calls(make_driver(machine), ("write", {"axis.z": 0.0}))


def test_linuxcnc_going_away_is_a_disconnect(machine):
    """When LinuxCNC shuts down, read and write raise DriverDisconnectedError, and so does open until it is back.

    Last in the module: it stops the module's LinuxCNC.
    """

    async def scenario() -> list[BaseException]:
        driver = make_driver(machine)
        await driver.open()
        await driver.read(["T-spindle-degC"])
        await asyncio.to_thread(machine.stop)
        raised = []
        for call in (
            driver.read(["T-spindle-degC"]),
            driver.write({"axis.z": 0.0}),
            driver.open(),
        ):
            try:
                await asyncio.wait_for(call, 10.0)
            except BaseException as exc:
                raised.append(exc)
        await driver.close()
        return raised

    raised = asyncio.run(scenario())
    assert len(raised) == 3
    assert all(isinstance(e, DriverDisconnectedError) for e in raised), raised
    print("LinuxCNC gone:", *(str(e) for e in raised), sep="\n  ")
