"""The simulated Profibus gateway on its own: publishing, what it refuses, and its faults as a peer sees them."""

from __future__ import annotations

import asyncio
import math
import socket
import time
from pathlib import Path

import can
import pytest
from pymodbus.client import AsyncModbusTcpClient

from compd.sim.plc.gateway import GatewayServer

from ..drivers.gateway_setup import (
    can_settings,
    channel_name,
    make_driver,
    make_server,
    modbus_settings,
)
from ..drivers.modbus_server import free_port


def test_publish_refuses_unknown_addresses_and_bad_bits_and_changes_nothing():
    """An unknown address or a bit of 2 raise ValueError naming it; the image is unchanged."""
    server = make_server(modbus_settings(502))
    before = bytes(server.input_image)
    for bad, match in (
        ({"in:0:int16": 1.0, "in:20:int16": 1.0}, "not an input address"),
        ({"in:0:int16": 1.0, "in:14.2": 2.0}, "a bit holds 0 or 1"),
    ):
        with pytest.raises(ValueError, match=match):
            server.publish(bad)
        assert bytes(server.input_image) == before


def test_an_integer_sensor_saturates_and_a_broken_one_reads_its_minimum():
    """Like the Modbus PLC: an int16 beyond its range reads 32767 (never wrapped), NaN the wire-break -32768."""
    server = make_server(modbus_settings(502))
    server.publish({"in:0:int16": 40000.0})
    assert server.input_image[0:2] == (32767).to_bytes(2, "big", signed=True)
    server.publish({"in:0:int16": math.nan})
    assert server.input_image[0:2] == (-32768).to_bytes(2, "big", signed=True)


def test_a_failed_float_sensor_can_be_published_as_nan():
    """A float input may hold NaN (a failed sensor); the driver reads it back as NaN for the loop's checks."""
    settings = can_settings(channel_name())
    server = make_server(settings)
    server.publish({"in:4:float32:word=big:byte=big": math.nan})

    async def scenario() -> float:
        await server.start()
        driver = make_driver(settings)
        await driver.open()
        try:
            return (await driver.read(["in:4:float32:word=big:byte=big"]))[
                "in:4:float32:word=big:byte=big"
            ]
        finally:
            await driver.close()
            await server.stop()

    assert math.isnan(asyncio.run(scenario()))


def test_modbus_writes_outside_the_output_area_and_other_devices_are_refused():
    """Holding registers outside the output area, input registers, and another device id are refused."""
    settings = modbus_settings(free_port())
    written: list[tuple[str, float]] = []
    server = make_server(settings, written)

    async def scenario() -> list[bool]:
        await server.start()
        client = AsyncModbusTcpClient("127.0.0.1", port=settings.port, timeout=0.5, retries=0)
        await client.connect()
        try:
            replies = [
                await client.write_registers(99, [1, 2], device_id=1),  # one below the area
                await client.write_registers(107, [1, 2], device_id=1),  # one past its end
                await client.read_input_registers(10, count=17, device_id=1),
                await client.write_registers(100, [1], device_id=1),  # inside: accepted
            ]
            return [r.isError() for r in replies]
        finally:
            client.close()
            await server.stop()

    assert asyncio.run(scenario()) == [True, True, True, False]
    assert dict(written) == {"out:0:int32": 65536.0}


def test_can_output_frame_with_a_wrong_length_is_ignored_and_counted():
    """An RPDO of the wrong length never reaches on_write: the gateway counts it and keeps its image."""
    settings = can_settings(channel_name())
    written: list[tuple[str, float]] = []
    server = make_server(settings, written)

    async def scenario() -> None:
        await server.start()
        bus = can.Bus(interface="virtual", channel=settings.channel)
        try:
            bus.send(can.Message(arbitration_id=0x205, data=b"\x01\x02\x03", is_extended_id=False))
            bus.send(
                can.Message(arbitration_id=0x205, data=bytes(range(1, 9)), is_extended_id=False)
            )
            deadline = time.monotonic() + 30  # a hang guard: the loop ends once written
            while not written and time.monotonic() < deadline:
                await asyncio.sleep(0.01)
        finally:
            bus.shutdown()
            await server.stop()

    asyncio.run(scenario())
    assert server.malformed_received == 1
    # bytes 01 02 03 04 little-endian, as the settings say
    assert ("out:0:int32", float(0x04030201)) in written


def test_a_busy_port_is_a_clear_start_error():
    """A port in use fails start() with RuntimeError naming host and port."""
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        server = make_server(modbus_settings(port))
        with pytest.raises(RuntimeError, match=f"127.0.0.1:{port}"):
            asyncio.run(server.start())


def test_inputs_must_lie_in_the_area():
    """An input address outside the configured input area is refused when the gateway is built."""
    with pytest.raises(ValueError, match=r"input address 'in:40:int16'.*outside the in area"):
        GatewayServer(
            modbus_settings(502),
            inputs=["in:40:int16"],
            outputs=[],
            on_write=lambda a, v: None,
            base_dir=Path(),
        )
