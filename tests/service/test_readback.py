"""The offset never jumps: compd slews from what the PLC's offset register holds, at start and after a reset.

Every test runs the service on virtual time against a real Modbus TCP PLC
(the simulated machine's server, :mod:`compd.sim.plc.modbus`) in the same
event loop. The PLC reports every value written to it, so the tests judge
what the machine received: each offset within one slew step of what the
register held just before. "The PLC program" (a restart that clears the
register, another writer) is a second Modbus client writing the register.
"""

from __future__ import annotations

import asyncio
import contextlib
import csv
import json
import math
import struct
import tempfile
from collections.abc import Awaitable, Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from compd.drivers.modbus.addresses import parse_address
from compd.drivers.modbus.driver import ModbusDriver
from compd.files.yamlplace import resolve_path
from compd.service.config.loading import Config, load_config
from compd.service.daemon import Service
from compd.service.loop.clock import VirtualClock
from compd.service.loop.compensator import TickRecord
from compd.service.loop.safety import SIGNAL_BIT0, Level
from compd.service.store.state import STATE_FILE
from compd.sim.plc.modbus import ModbusPlcServer
from tests.ports import free_port

OFFSET = "holding:100:int32"  # 0.1 um counts (encoding scale 10)
STATUS = "holding:110:uint32"
HEARTBEAT = "holding:112"
STEP_COUNTS = 10  # max_rate_um_per_s 1.0 x period_s 1.0, in 0.1 um
#: Constant inputs (raw counts, 0.01 degC / rpm / 0.01 kW) the PLC serves.
INPUTS = {
    "input:0:int16": 3000,
    "input:1:int16": 2800,
    "input:2:int16": 2300,
    "input:3:int16": 2000,
    "input:4:uint16": 0,
    "input:5:uint16": 0,
    "input:6:int16": 3000,  # the spindle's second sensor
    "input:7:int16": 2000,  # the air's
}
MISMATCH_BIT = 1 << (SIGNAL_BIT0 + len(INPUTS))  # eight signals: bit 16 of a uint32 word


def plc_config(directory: Path, **output: Any) -> Config:
    """The bundled simulated-machine config (Modbus TCP, Z int32 in 0.1 um) against a PLC on a free port."""
    doc = yaml.safe_load(resolve_path("bundled:simulated.yaml", Path(".")).read_text())
    del doc["simulation"]
    doc["model"] = str(resolve_path("bundled:simulated_model.yaml", Path(".")))
    doc["drivers"]["plc"]["settings"]["port"] = free_port()
    doc["state"] = {"directory": str(directory / "state"), "save_every_ticks": 5}
    doc["recorder"] = {"enabled": True, "directory": str(directory / "records")}
    doc["outputs"]["Z"].update(output)
    path = directory / "compd.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return load_config(path)


@dataclass
class Plc:
    """A Modbus PLC that logs what it receives; ``program`` writes the offset register like a PLC program."""

    config: Config
    #: Where the offset is written (the config's ``outputs.Z.address``).
    offset: str = OFFSET
    #: (address, raw, by compd?) for every value written, in order.
    received: list[tuple[str, float, bool]] = field(default_factory=list)
    server: ModbusPlcServer = field(init=False)
    _programming: bool = False

    def __post_init__(self) -> None:
        self.server = ModbusPlcServer(
            self.config.driver_settings["plc"],  # type: ignore[arg-type]
            inputs=list(INPUTS),
            outputs=[self.offset, STATUS, HEARTBEAT],
            on_write=lambda address, raw: self.received.append(
                (address, raw, not self._programming)
            ),
            base_dir=self.config.base_dir,
        )

    async def start(self) -> None:
        await self.server.start()
        self.server.publish(INPUTS)

    async def program(self, offset_um: float) -> None:
        """The PLC itself sets its offset register (a restart that clears it, its own program)."""
        await self.program_raw(round(offset_um * 10))

    async def program_raw(self, raw: float) -> None:
        """The PLC's program puts ``raw`` into the offset register as is: NaN, inf and 3e38 too."""
        settings = self.config.driver_settings["plc"]
        point = parse_address(self.offset)
        code = {"int16": "h", "int32": "i", "float32": "f", "float64": "d"}[point.codec.type]
        data = struct.pack(">" + code, raw if code in "fd" else int(raw))
        words = [int.from_bytes(data[i : i + 2], "big") for i in range(0, len(data), 2)]
        driver = ModbusDriver(settings, now=lambda: 0.0, base_dir=Path())  # type: ignore[arg-type]
        await driver.open()
        self._programming = True
        try:
            device = settings.device_id  # type: ignore[attr-defined]
            await driver.write_registers(point.address, words, device=device, what="PLC program")
        finally:
            self._programming = False
            await driver.close()

    def offsets(self) -> list[tuple[float, bool]]:
        """Every value the offset register received (raw counts), and whether compd sent it."""
        return [(raw, ours) for address, raw, ours in self.received if address == self.offset]

    def largest_step_counts(self) -> float:
        """The largest change compd made to what the register held (counts); 0 before the first write."""
        held, largest = 0.0, 0.0
        for raw, by_compd in self.offsets():
            if by_compd:
                largest = max(largest, abs(raw - held))
            held = raw
        return largest


def run_against(
    plc: Plc,
    duration_s: float,
    *,
    held_um: float | None = None,
    before_tick: Mapping[int, Callable[[], Awaitable[None]]] | None = None,
    clock: VirtualClock | None = None,
) -> tuple[Service, list[TickRecord]]:
    """Start the PLC (holding ``held_um``), run compd against it for ``duration_s``, stop both."""
    records: list[TickRecord] = []

    async def scenario() -> Service:
        await plc.start()
        try:
            if held_um is not None:
                await plc.program(held_um)
            service = Service(
                plc.config, clock=clock or VirtualClock(), control=False, on_tick=records.append
            )
            tick = service.compensator.tick

            async def tick_with_faults(t_s: float) -> TickRecord:
                fault = (before_tick or {}).get(len(records))
                if fault is not None:
                    await fault()
                # Virtual time outruns a reconnect's real I/O: let it finish, as a second would.
                for _ in range(1000):
                    if not any(link.connecting for link in service.links.values()):
                        break
                    await asyncio.sleep(0.001)
                return await tick(t_s)

            service.compensator.tick = tick_with_faults  # type: ignore[method-assign]
            await service.run(duration_s=duration_s)
            return service
        finally:
            await plc.server.stop()

    return asyncio.run(scenario()), records


def test_a_start_slews_from_what_the_plc_holds_not_from_zero(tmp_path):
    """A PLC holding 9.3 um and a garbage state file: the first write is one slew step from 9.3 um, not 0."""
    plc = Plc(plc_config(tmp_path))
    (plc.config.state_dir).mkdir(parents=True)
    (plc.config.state_dir / STATE_FILE).write_bytes(b"\x00garbage{")
    service, _ = run_against(plc, 20.0, held_um=9.3)
    first, _ = plc.offsets()[1]  # [0] is the PLC's own 9.3 um
    assert abs(first - 93) <= STEP_COUNTS
    assert plc.largest_step_counts() <= STEP_COUNTS
    status = service.status()
    assert status["counters"]["offset_mismatches"] == 0  # a seed is no mismatch
    assert status["offsets_held_um"]["Z"] == plc.offsets()[-1][0] / 10


def test_a_plc_that_clears_its_offset_register_is_followed_from_zero(tmp_path):
    """A PLC restart clearing the register mid-run: compd slews on from 0, and counts, flags and records it."""
    plc = Plc(plc_config(tmp_path))

    async def restart_clearing_the_register() -> None:
        await plc.server.stop()
        await plc.server.start()
        await plc.program(0.0)

    service, records = run_against(
        plc, 60.0, held_um=40.0, before_tick={10: restart_clearing_the_register}
    )
    assert plc.largest_step_counts() <= STEP_COUNTS
    assert service.status()["counters"]["offset_mismatches"] == 1
    flagged = [r for r in records if r.status & MISMATCH_BIT]
    assert len(flagged) == 1 and flagged[0].status & 0b11 == Level.DEGRADED
    assert flagged[0].readback_um["Z"] == 0.0
    # The recorder holds what the PLC acknowledged: each row's offset is the register's next value.
    service.recorder.close()
    (path,) = (tmp_path / "records").glob("compd-*.csv")
    with path.open() as f:
        rows = csv.DictReader(line for line in f if not line.startswith("#"))  # metadata lines
        recorded = [float(row["offset.Z_um"] or "nan") for row in rows]
    by_compd = [raw / 10 for raw, ours in plc.offsets() if ours]
    assert math.isnan(recorded[10])  # the tick the PLC was down: nothing acknowledged
    assert [v for v in recorded if math.isfinite(v)] == by_compd


def test_a_float_encoding_on_an_integer_register_reads_back_without_mismatches(tmp_path):
    """A float offset written to an int32 register is rounded as the register would: no false mismatches."""
    slow = {"encoding": {"type": "float", "scale": 10}, "max_rate_um_per_s": 0.33}
    plc = Plc(plc_config(tmp_path, **slow))  # steps of 3.3 counts: the register rounds them
    assert plc.config.whole_counts == {"Z": True}
    service, records = run_against(plc, 30.0, held_um=20.0)
    assert service.status()["counters"]["offset_mismatches"] == 0
    assert all(r.status & MISMATCH_BIT == 0 for r in records)
    assert plc.largest_step_counts() <= 3


def test_an_offset_point_without_readback_resumes_the_saved_offset(tmp_path):
    """With readback off the seed is the saved offset (range-checked), as before readback existed."""
    plc = Plc(plc_config(tmp_path, readback=False))
    assert not plc.config.readback["Z"]
    run_against(plc, 10.0)
    saved = json.loads((plc.config.state_dir / STATE_FILE).read_text())
    assert saved["offsets_um"]["Z"] == plc.offsets()[-1][0] / 10


def test_a_saved_offset_beyond_the_clamp_is_not_resumed(tmp_path):
    """A saved Z of 140 um or 1e9 um beyond a 50 um clamp is not resumed: every write goes through, a step at a time."""
    plc = Plc(plc_config(tmp_path, readback=False))
    run_against(plc, 10.0)
    state = plc.config.state_dir / STATE_FILE
    saved = json.loads(state.read_text())
    clock = VirtualClock(wall0_unix_s=saved["saved_at_unix_s"] + 1.0)
    for bogus in (140.0, 1e9):
        saved["offsets_um"]["Z"] = bogus
        state.write_text(json.dumps(saved))
        plc = Plc(plc_config(tmp_path, readback=False, max_offset_um=50))
        service, records = run_against(plc, 5.0, clock=clock)
        assert not service.resumed
        assert all(r.written for r in records)  # not one write refused (int32 overflow)
        assert plc.largest_step_counts() <= STEP_COUNTS


def test_a_start_that_fails_before_its_first_tick_writes_nothing(tmp_path):
    """A daemon that dies before its first tick leaves the PLC's offset, status and heartbeat untouched."""
    plc = Plc(plc_config(tmp_path))

    async def scenario() -> None:
        await plc.start()
        try:
            await plc.program(3.4)
            service = Service(plc.config, clock=VirtualClock(), control=False)

            async def broken(t_s: float) -> TickRecord:
                raise RuntimeError("the model blew up")

            service.compensator.tick = broken  # type: ignore[method-assign]
            with contextlib.suppress(RuntimeError):
                await service.run(duration_s=5.0)
        finally:
            await plc.server.stop()

    asyncio.run(scenario())
    assert plc.received == [(OFFSET, 34.0, False)]


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    held_um=st.floats(-150, 150, allow_nan=False),
    state=st.one_of(
        st.none(),
        st.binary(max_size=40),
        st.floats(allow_nan=True, allow_infinity=True).map(
            lambda z: json.dumps({"format": "compd.state/1", "offsets_um": {"Z": z}}).encode()
        ),
    ),
    faults=st.dictionaries(
        st.integers(1, 18),
        st.tuples(st.floats(-150, 150, allow_nan=False), st.booleans()),
        max_size=3,
    ),
)
def test_every_value_the_plc_receives_is_one_slew_step_from_what_it_held(held_um, state, faults):
    """Random held values, state files, PLC restarts and resets: no write moves the register over a slew step."""
    with tempfile.TemporaryDirectory(prefix="compd-rb-") as directory:
        plc = Plc(plc_config(Path(directory)))
        if state is not None:
            plc.config.state_dir.mkdir(parents=True)
            (plc.config.state_dir / STATE_FILE).write_bytes(state)

        def fault(value_um: float, restart: bool) -> Callable[[], Awaitable[None]]:
            async def reset() -> None:
                if restart:
                    await plc.server.stop()
                    await plc.server.start()
                await plc.program(value_um)

            return reset

        service, records = run_against(
            plc, 25.0, held_um=held_um, before_tick={k: fault(*f) for k, f in faults.items()}
        )
    assert plc.largest_step_counts() <= STEP_COUNTS
    assert records[-1].written  # and compd went on writing after the last fault
    assert service.status()["counters"]["offset_mismatches"] <= len(faults)
