"""The simulated PLC's Modbus TCP server against compd's own Modbus driver, in one event loop."""

from __future__ import annotations

import asyncio
import math
import socket
import time
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

import pytest
from pymodbus.client import AsyncModbusTcpClient

from compd.drivers.modbus.addresses import parse_address
from compd.drivers.modbus.driver import ModbusDriver
from compd.drivers.modbus.settings import ModbusSettings
from compd.errors import DriverProtocolError
from compd.service.loop.clock import VirtualClock
from compd.service.loop.links import DriverLink
from compd.sim.plc.modbus import ModbusPlcServer
from tests.reconnect import seconds_until_read

from ..drivers.modbus_server import free_port

# What a machine's PLC maps for compd: raw values as the driver returns them.
INPUTS = {
    "input:10:int16": -1234,  # -12.34 degC at the config's scale 0.01
    "input:11:float32:word=little": 21.5,
    "input:13:uint32": 3_000_000_000,
    "input:15:float64:byte=little:word=little": -0.125,
    "holding:40": 3000,  # spindle speed (rpm) in a holding register
    "coil:2": 1,
    "discrete:5": 1,
    "discrete:6": 0,
    "input:0:int16:device=7": 42,  # a second device behind the same gateway
}
OUTPUTS = [
    "holding:200:int32:word=little",  # X offset in 0.1 um
    "holding:202:int32",  # Y offset
    "holding:210",  # status word
    "holding:211",  # heartbeat
    "coil:8",  # compensation active
]

Writes = list[tuple[str, float]]


def plc(port: int, writes: Writes, **settings: Any) -> ModbusPlcServer:
    return ModbusPlcServer(
        ModbusSettings(host="127.0.0.1", port=port, **settings),
        inputs=list(INPUTS),
        outputs=OUTPUTS,
        on_write=lambda address, raw: writes.append((address, raw)),
        base_dir=Path(),
    )


def driver(port: int) -> ModbusDriver:
    settings = ModbusSettings(host="127.0.0.1", port=port, request_timeout_s=0.5)
    return ModbusDriver(settings, now=time.monotonic, base_dir=Path())


def serve(scenario: Callable[[ModbusPlcServer, ModbusDriver, Writes], Awaitable[None]]) -> Writes:
    """Run ``scenario`` with a started PLC (INPUTS published) and an open driver; the writes it saw."""
    writes: Writes = []

    async def main() -> None:
        port = free_port()
        server = plc(port, writes)
        await server.start()
        server.publish(INPUTS)
        client = driver(port)
        try:
            await client.open()
            await scenario(server, client, writes)
        finally:
            await client.close()
            await server.stop()

    asyncio.run(main())
    return writes


def test_published_values_read_back_exactly_in_every_type_and_order():
    """Every published raw value reads back unchanged through the driver: any table, type, order and device."""

    async def scenario(server: ModbusPlcServer, client: ModbusDriver, writes: Writes) -> None:
        assert await client.read(list(INPUTS)) == {k: float(v) for k, v in INPUTS.items()}
        server.publish({"input:10:int16": 2500, "coil:2": 0})
        values = await client.read(["input:10:int16", "coil:2"])
        assert values == {"input:10:int16": 2500.0, "coil:2": 0.0}

    assert serve(scenario) == []


def test_the_words_on_the_wire_are_the_codecs_for_every_type_and_order():
    """Registers served for each type and byte/word order, at range extremes too, are what compd's codec encodes."""
    cases = {
        "bool": [0, 1],
        "int16": [-32768, -1234, 32767],
        "uint16": [0, 65535],
        "int32": [-(2**31), -123_456, 2**31 - 1],
        "uint32": [0, 3_000_000_000, 2**32 - 1],
        "float32": [21.5, -3.4e38, 1e-40],
        "float64": [-0.125, 1e300, math.pi],
    }
    points: dict[str, float] = {}
    at = 0
    for kind, values in cases.items():
        for byte in ("big", "little"):
            for word in ("big", "little"):
                for value in values:
                    points[f"input:{at}:{kind}:byte={byte}:word={word}"] = value
                    at += parse_address(f"input:0:{kind}").count

    async def main() -> list[int]:
        port = free_port()
        server = ModbusPlcServer(
            ModbusSettings(host="127.0.0.1", port=port),
            inputs=list(points),
            outputs=[],
            on_write=lambda a, v: None,
            base_dir=Path(),
        )
        await server.start()
        server.publish(points)
        client = AsyncModbusTcpClient("127.0.0.1", port=port, timeout=0.5, retries=0)
        await client.connect()
        try:
            words: list[int] = []
            for start in range(0, at, 100):
                reply = await client.read_input_registers(start, count=min(100, at - start))
                words += reply.registers
        finally:
            client.close()
            await server.stop()
        return words

    words = asyncio.run(main())
    for address, value in points.items():
        point = parse_address(address)
        served = words[point.address : point.address + point.count]
        assert served == point.codec.encode_registers(value), address


def test_outputs_read_zero_until_written_and_then_what_was_written():
    """An output address reads 0 before compd's first write and its last written value after it."""

    async def scenario(server: ModbusPlcServer, client: ModbusDriver, writes: Writes) -> None:
        assert await client.read(["holding:202:int32", "coil:8"]) == {
            "holding:202:int32": 0.0,
            "coil:8": 0.0,
        }
        await client.write({"holding:202:int32": -70000, "coil:8": 1})
        assert await client.read(["holding:202:int32", "coil:8"]) == {
            "holding:202:int32": -70000.0,
            "coil:8": 1.0,
        }

    serve(scenario)


def test_offsets_status_and_heartbeat_reach_on_write_decoded_once_each():
    """One tick's writes (int32 offsets, status word, heartbeat, a coil) are each reported once, decoded."""
    tick = {
        "holding:200:int32:word=little": -123_456,
        "holding:202:int32": 2_000_000_000,
        "holding:210": 0b1011,
        "holding:211": 65535,
        "coil:8": 1,
    }

    async def scenario(server: ModbusPlcServer, client: ModbusDriver, writes: Writes) -> None:
        requests = client.requests
        await client.write(tick)
        # The driver merges 200..211 into two blocks (200-203, 210-211) plus one coil write.
        assert client.requests - requests == 3

    writes = serve(scenario)
    assert sorted(writes) == sorted((k, float(v)) for k, v in tick.items())


def test_a_value_split_over_two_requests_is_reported_when_its_last_word_arrives():
    """An int32 written one register per request is reported once, after the second, with the whole value."""

    async def main() -> Writes:
        writes: Writes = []
        port = free_port()
        server = plc(port, writes)
        await server.start()
        client = AsyncModbusTcpClient("127.0.0.1", port=port, timeout=0.5, retries=0)
        await client.connect()
        try:
            await client.write_register(202, 0xFFFF, device_id=1)
            assert writes == []
            await client.write_register(203, 0xFFFE, device_id=1)
            assert writes == [("holding:202:int32", -2.0)]
        finally:
            client.close()
            await server.stop()
        return writes

    assert asyncio.run(main()) == [("holding:202:int32", -2.0)]


@pytest.mark.parametrize(
    "refused",
    [
        {"holding:40": 1},  # an input the PLC serves in a holding register
        {"holding:300": 1},  # an address the config does not name
        {"holding:211:uint32": 1},  # overlaps the heartbeat and runs past it
        {"coil:2": 0},  # an input coil
        {"holding:210:device=9": 1},  # a device no address uses
    ],
    ids=["input", "unknown", "overlap", "input coil", "unknown device"],
)
def test_writes_outside_the_outputs_are_refused_and_change_nothing(refused: dict[str, float]):
    """A write to an input, an unknown address or an unknown device is refused by a Modbus exception, unreported."""

    async def scenario(server: ModbusPlcServer, client: ModbusDriver, writes: Writes) -> None:
        with pytest.raises(DriverProtocolError, match=r"refused \(exception code (2|11)"):
            await client.write(refused)
        assert await client.read(["holding:40", "coil:2", "holding:211"]) == {
            "holding:40": 3000.0,
            "coil:2": 1.0,
            "holding:211": 0.0,
        }

    assert serve(scenario) == []


def test_publish_refuses_unknown_addresses_and_bad_bits_and_changes_nothing():
    """publish() is all or none: an unknown address or a coil value other than 0/1 is a ValueError."""

    async def scenario(server: ModbusPlcServer, client: ModbusDriver, writes: Writes) -> None:
        with pytest.raises(ValueError, match=r"'input:99' is not an input address"):
            server.publish({"input:10:int16": 1, "input:99": 1})
        with pytest.raises(ValueError, match=r"coil:2: a coil holds 0 or 1"):
            server.publish({"input:13:uint32": 7, "coil:2": 0.5})
        assert await client.read(["input:10:int16", "input:13:uint32"]) == {
            "input:10:int16": -1234.0,
            "input:13:uint32": 3_000_000_000.0,
        }

    serve(scenario)


def test_an_integer_sensor_saturates_out_of_range_and_reads_its_minimum_when_broken():
    """Like a PLC's analogue input: beyond the type's range it saturates (never wraps); NaN is the wire-break code."""

    async def scenario(server: ModbusPlcServer, client: ModbusDriver, writes: Writes) -> None:
        server.publish({"input:10:int16": 40000, "input:13:uint32": -5})
        assert await client.read(["input:10:int16", "input:13:uint32"]) == {
            "input:10:int16": 32767.0,
            "input:13:uint32": 0.0,
        }
        server.publish({"input:10:int16": math.nan})
        assert await client.read(["input:10:int16"]) == {"input:10:int16": -32768.0}

    serve(scenario)


def test_a_failed_float_sensor_can_be_published_as_nan():
    """A float register can hold NaN (a failed sensor on the PLC): the driver reads NaN, in any word order."""

    async def scenario(server: ModbusPlcServer, client: ModbusDriver, writes: Writes) -> None:
        server.publish(
            {
                "input:11:float32:word=little": math.nan,
                "input:15:float64:byte=little:word=little": -math.inf,
            }
        )
        values = await client.read(
            ["input:11:float32:word=little", "input:15:float64:byte=little:word=little"]
        )
        assert math.isnan(values["input:11:float32:word=little"])
        assert values["input:15:float64:byte=little:word=little"] == -math.inf

    serve(scenario)


def test_configurations_the_server_cannot_serve_are_refused_with_the_fix():
    """RTU, an input-table output and a malformed address fail at construction, naming the address and the fix."""
    with pytest.raises(ValueError, match=r"Modbus TCP only.*transport: tcp"):
        ModbusPlcServer(
            ModbusSettings(transport="rtu", serial_port="/dev/ttyUSB0"),
            inputs=[],
            outputs=[],
            on_write=lambda a, v: None,
            base_dir=Path(),
        )
    settings = ModbusSettings(host="127.0.0.1", port=1502)
    with pytest.raises(ValueError, match=r"'input:3'.*use a holding register or a coil"):
        ModbusPlcServer(
            settings, inputs=[], outputs=["input:3"], on_write=lambda a, v: None, base_dir=Path()
        )
    with pytest.raises(ValueError, match="input address 'holding:x'"):
        ModbusPlcServer(
            settings, inputs=["holding:x"], outputs=[], on_write=lambda a, v: None, base_dir=Path()
        )


def test_a_busy_port_is_a_clear_start_error():
    """start() on a port another socket holds raises a RuntimeError naming host and port."""

    async def main() -> None:
        with socket.create_server(("127.0.0.1", 0)) as taken:
            port = taken.getsockname()[1]
            server = plc(port, [])
            with pytest.raises(RuntimeError, match=f"cannot listen on 127.0.0.1:{port}"):
                await server.start()
            await server.stop()

    asyncio.run(main())


def test_restart_drops_the_connection_keeps_the_values_and_the_link_reconnects():
    """stop() then start() is a PLC restart: reads fail meanwhile, the link reconnects, published values survive."""

    async def main() -> tuple[float, DriverLink]:
        writes: Writes = []
        port = free_port()
        server = plc(port, writes)
        await server.start()
        server.publish(INPUTS)
        clock = VirtualClock()  # the backoff's clock: the retries counted, not the machine's speed
        # timeout_s only ends a hung read: a short one times out good reads on a busy host.
        link = DriverLink("plc", driver(port), clock, timeout_s=10.0, backoff_min_s=0.05)
        await link.open()
        assert await link.read(["input:10:int16"]) == {"input:10:int16": -1234.0}
        await server.stop()
        await asyncio.sleep(0.05)
        assert await link.read(["input:10:int16"]) == {}
        assert await link.write({"holding:211": 1}) is False
        await server.start()  # rebinds the same port at once
        resumed_s = await seconds_until_read(link, clock, ["input:10:int16"])
        assert await link.read(["input:10:int16", "coil:2"]) == {
            "input:10:int16": -1234.0,
            "coil:2": 1.0,
        }
        assert await link.write({"holding:211": 2}) is True
        assert writes == [("holding:211", 2.0)]
        await link.close()
        await server.stop()
        return resumed_s, link

    resumed_s, link = asyncio.run(main())
    assert resumed_s < 5.0 and link.reconnects == 1
