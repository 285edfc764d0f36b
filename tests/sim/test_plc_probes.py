"""The simulated PLC's probe cycles, read and answered by a Modbus client as compd would.

The machine is built from the bundled simulated config plus a probes section
(Z: an int32 value at 0.1 um in holding 120-121, the counter at 122, compd's
echo at 123 and probe status word at 124, a uint32 touch stamp at 125-126)
and advanced on its own virtual clock; a pymodbus client on 127.0.0.1 reads
and writes the registers. Nothing here depends on real time.
"""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

import pytest
import yaml
from pymodbus.client import AsyncModbusTcpClient

from compd.errors import ConfigFileError
from compd.files.yamlplace import resolve_path
from compd.service.config.loading import load_config
from compd.sim.plc.build import build_machine, served_addresses
from compd.sim.plc.machine import SimulatedMachine
from tests.ports import free_port

SIMULATED = resolve_path("bundled:simulated.yaml", Path("."))
MODEL = resolve_path("bundled:simulated_model.yaml", Path("."))
WALL0_UNIX_S = 1_700_000_000.0
VALUE_RESOLUTION_UM = 0.1
Z_AXIS = 2

PROBE_REGISTERS = {
    "driver": "plc",
    "value_address": "holding:120:int32",
    "value_scale": VALUE_RESOLUTION_UM,
    "counter_address": "holding:122",
    "echo_address": "holding:123",
    "status_address": "holding:124",
    "touched_at_address": "holding:125:uint32",
}

NO_STATUS = {**PROBE_REGISTERS, "status_address": None}
MISPROBE_ON_X = {"at_s": 1, "error_um": 5, "axis": "X"}


def probed_config(tmp_path: Path, probes: dict[str, Any], **section: Any) -> Path:
    """The bundled simulated config on a free port, Z probed, ``simulation.probes`` = ``probes``."""
    doc: dict[str, Any] = yaml.safe_load(SIMULATED.read_text())
    doc["model"] = str(MODEL)
    doc["drivers"]["plc"]["settings"]["port"] = free_port()
    doc["state"] = {"directory": str(tmp_path / "state")}
    doc["probes"] = {"every_h": 2, "axes": {"Z": PROBE_REGISTERS}, **section}
    doc["simulation"] = {"scenario": "production", "hours": 8, "seed": 3, "probes": probes}
    path = tmp_path / "compd.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def machine_of(path: Path) -> SimulatedMachine:
    machine = build_machine(load_config(path))
    machine.wall0_unix_s = WALL0_UNIX_S
    return machine


class Plc:
    """A pymodbus client on the machine's PLC, reading the probe registers as compd does."""

    def __init__(self, client: AsyncModbusTcpClient) -> None:
        self.client = client

    async def registers(self) -> tuple[float, int, int]:
        """(value um, counter, touched-at unix s)."""
        reply = await self.client.read_holding_registers(120, count=7)
        assert not reply.isError(), reply
        words = reply.registers
        convert, types = self.client.convert_from_registers, self.client.DATATYPE
        value = convert(words[0:2], types.INT32)
        touched_at = convert(words[5:7], types.UINT32)
        assert isinstance(value, int) and isinstance(touched_at, int)
        return value * VALUE_RESOLUTION_UM, words[2], touched_at

    async def counter(self) -> int:
        return (await self.registers())[1]

    async def write(self, address: int, value: int) -> None:
        reply = await self.client.write_register(address, value)
        assert not reply.isError(), reply

    async def write_offset_um(self, offset_um: float) -> None:
        """The Z offset (int32 at 0.1 um, holding 100-101), as compd writes it."""
        words = self.client.convert_to_registers(round(offset_um * 10), self.client.DATATYPE.INT32)
        reply = await self.client.write_registers(100, words)
        assert not reply.isError(), reply


def run(
    path: Path, scenario: Callable[[SimulatedMachine, Plc], Awaitable[None]]
) -> SimulatedMachine:
    """Start the machine of ``path``, run ``scenario`` with a connected client, stop both."""
    machine = machine_of(path)

    async def main() -> None:
        await machine.start()
        port = yaml.safe_load(path.read_text())["drivers"]["plc"]["settings"]["port"]
        client = AsyncModbusTcpClient("127.0.0.1", port=port, timeout=1, retries=0)
        try:
            assert await client.connect()
            await scenario(machine, Plc(client))
        finally:
            client.close()
            await machine.stop()

    asyncio.run(main())
    return machine


def test_a_timer_cycle_writes_the_residue_at_the_touch_its_stamp_then_the_counter_a_cycle_later(
    tmp_path: Path,
) -> None:
    """An hourly touch; 60 s later the value (error + offset + noise), the touch's unix time, the counter + 1."""
    path = probed_config(tmp_path, {"every_h": 1, "cycle_s": 60})

    async def scenario(machine: SimulatedMachine, plc: Plc) -> None:
        await plc.write_offset_um(-12.5)
        await machine.advance_to(3600 + 59)
        assert await plc.counter() == 0, "the value is written at the cycle's end, not its touch"
        await machine.advance_to(3600 + 60)
        value_um, count, touched_at = await plc.registers()
        (cycle,) = machine.probe_cycles
        assert count == cycle.count == 1
        assert cycle.reason == "timer" and cycle.touched_s == 3600 and cycle.written_s == 3660
        assert touched_at == WALL0_UNIX_S + 3600
        assert cycle.offset_um == -12.5
        assert cycle.true_error_um == machine.true_um[3600, Z_AXIS]
        assert cycle.residue_um == cycle.true_error_um - 12.5
        assert cycle.value_um == cycle.residue_um + cycle.noise_um
        assert value_um == pytest.approx(cycle.value_um, abs=VALUE_RESOLUTION_UM / 2 + 1e-9)

    machine = run(path, scenario)
    assert machine.probe_cycles[0].noise_um != 0.0


def test_the_counter_goes_up_once_per_cycle(tmp_path: Path) -> None:
    """Four hourly cycles, four counts: read after each cycle, the counter is its count, none skipped or repeated."""
    path = probed_config(tmp_path, {"every_h": 1})

    async def scenario(machine: SimulatedMachine, plc: Plc) -> None:
        seen = []
        for hour in range(1, 5):
            await machine.advance_to(hour * 3600 + 30)
            seen.append(await plc.counter())
            await machine.advance_to(hour * 3600 + 61)
            seen.append(await plc.counter())
        assert seen == [0, 1, 1, 2, 2, 3, 3, 4]
        assert [c.count for c in machine.probe_cycles] == [1, 2, 3, 4]
        assert [c.touched_s for c in machine.probe_cycles] == [3600, 7200, 10800, 14400]

    run(path, scenario)


def test_a_misprobe_adds_its_error_to_the_next_cycle_only(tmp_path: Path) -> None:
    """A chip on the datum ball at 5000 s: the 7200 s touch reads 50 um off, the ones before and after do not."""
    misprobe = {"at_s": 5000, "error_um": 50.0}
    path = probed_config(tmp_path, {"every_h": 1, "misprobes": [misprobe]})

    async def scenario(machine: SimulatedMachine, plc: Plc) -> None:
        await machine.advance_to(7200 + 60)
        value_um, _, _ = await plc.registers()
        assert value_um == pytest.approx(
            machine.probe_cycles[-1].residue_um + machine.probe_cycles[-1].noise_um + 50.0,
            abs=VALUE_RESOLUTION_UM / 2 + 1e-9,
        )
        await machine.advance_to(3 * 3600 + 60)

    machine = run(path, scenario)
    assert [c.misprobe_um for c in machine.probe_cycles] == [0.0, 50.0, 0.0]
    errors_um = [c.value_um - c.residue_um - c.noise_um for c in machine.probe_cycles]
    assert errors_um == pytest.approx([0.0, 50.0, 0.0], abs=1e-9)


def test_a_probe_due_bit_from_the_client_starts_a_cycle_and_no_other_within_the_gap(
    tmp_path: Path,
) -> None:
    """With when_due, status bit 0 starts a cycle at the next step; held, the next waits min_gap_h; cleared, none."""
    path = probed_config(tmp_path, {"when_due": True, "min_gap_h": 0.5, "cycle_s": 60})

    async def scenario(machine: SimulatedMachine, plc: Plc) -> None:
        await machine.advance_to(100)
        await plc.write(124, 0b10)  # "the model no longer describes the machine" only
        await machine.advance_to(1000)
        assert machine.probe_cycles == [] and await plc.counter() == 0
        await plc.write(124, 0b11)  # probe due
        await machine.advance_to(1061)
        assert await plc.counter() == 1
        assert machine.probe_cycles[0].reason == "due"
        assert machine.probe_cycles[0].touched_s == 1001
        await machine.advance_to(1001 + 1800 - 1)  # still due, but within min_gap_h of the touch
        assert await plc.counter() == 1
        await machine.advance_to(1001 + 1800 + 60)
        assert await plc.counter() == 2
        assert machine.probe_cycles[1].touched_s == 1001 + 1800
        await plc.write(124, 0)  # compd took the probe: nothing due
        await machine.advance_to(3 * 3600)
        assert await plc.counter() == 2

    machine = run(path, scenario)
    assert machine.probe_stations["Z"].log.status_word == 0
    assert machine.probe_stations["Z"].log.status_writes == 3


def test_the_echo_compd_writes_reaches_the_machine(tmp_path: Path) -> None:
    """compd's echo (the last count it took) lands in the axis's probe log; a write to the counter is refused."""
    path = probed_config(tmp_path, {"every_h": 1})

    async def scenario(machine: SimulatedMachine, plc: Plc) -> None:
        await machine.advance_to(3661)
        await plc.write(123, await plc.counter())
        refused = await plc.client.write_register(122, 7)
        assert refused.isError(), "the counter is the PLC's: compd only reads it"

    machine = run(path, scenario)
    log = machine.probe_stations["Z"].log
    assert (log.echo, log.echo_writes) == (1, 1)


def test_the_noise_is_drawn_from_the_seed(tmp_path: Path) -> None:
    """The same config probes the same noise in every run; another seed draws other noise."""

    def noise(seed: int) -> list[float]:
        path = probed_config(tmp_path, {"every_h": 0.5})
        doc = yaml.safe_load(path.read_text())
        doc["simulation"]["seed"] = seed
        path.write_text(yaml.safe_dump(doc))
        machine = machine_of(path)  # never started: publishing only fills its memory
        asyncio.run(machine.advance_to(3 * 3600))
        return [c.noise_um for c in machine.probe_cycles]

    first = noise(3)
    assert len(first) == 5 and first == noise(3)
    assert first != noise(4)


@pytest.mark.parametrize(
    ("probes", "section", "where"),
    [
        ({"every_h": 1}, {"enabled": False}, "simulation.probes"),
        ({"when_due": True}, {"axes": {"Z": NO_STATUS}}, "probes.axes.Z.status_address"),
        ({"every_h": 1, "misprobes": [MISPROBE_ON_X]}, {}, "simulation.probes.misprobes.0.axis"),
    ],
)
def test_probe_cycles_the_config_cannot_carry_are_refused_naming_the_place(
    tmp_path: Path, probes: dict[str, Any], section: dict[str, Any], where: str
) -> None:
    """Cycles without registers, a due bit compd never writes, a mis-probe off the probed axes: errors in place."""
    path = probed_config(tmp_path, probes, **section)
    with pytest.raises(ConfigFileError, match=where.replace(".", r"\.")):
        build_machine(load_config(path))


def test_simulation_probes_settings_are_strict(tmp_path: Path) -> None:
    """An unknown key or a negative noise in simulation.probes is a config error, not ignored."""
    for probes in ({"every_hours": 1}, {"noise_um": -1}):
        with pytest.raises(ConfigFileError, match="simulation"):
            build_machine(load_config(probed_config(tmp_path, probes)))


def test_the_plc_serves_the_probe_registers_beside_the_signals_and_outputs(tmp_path: Path) -> None:
    """compd reads value, counter and touch stamp; it writes echo and probe status (the soak's PLC too)."""
    inputs, outputs = served_addresses(load_config(probed_config(tmp_path, {})).doc, "plc")
    assert inputs[-3:] == ["holding:120:int32", "holding:122", "holding:125:uint32"]
    assert outputs[-2:] == ["holding:123", "holding:124"]
