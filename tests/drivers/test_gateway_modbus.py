"""The Profibus gateway driver over Modbus TCP (an Anybus-Communicator-like image) against the simulated gateway."""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from compd.drivers.gateway.driver import GatewayDriver, GatewaySettings
from compd.drivers.modbus.driver import ModbusDriver
from compd.drivers.modbus.settings import ModbusSettings
from compd.errors import ConfigFileError, DriverProtocolError, DriverTimeoutError
from compd.service.config.loading import parse_config
from compd.service.loop.clock import VirtualClock
from compd.service.loop.links import DriverLink
from compd.sim.plc.gateway import GatewayServer
from tests.reconnect import seconds_until_read

from .contract import ContractSetup, DriverContract
from .gateway_setup import INPUTS, ThreadedGateway, make_driver, make_server, modbus_settings
from .modbus_server import TcpProxy, free_port


async def served(settings: GatewaySettings, **options) -> tuple[GatewayServer, GatewayDriver]:
    server = make_server(settings, options.pop("written", None), **options)
    await server.start()
    driver = make_driver(settings)
    await driver.open()
    return server, driver


async def shut(server: GatewayServer, driver: GatewayDriver) -> None:
    await driver.close()
    await server.stop()


def requests(driver: GatewayDriver) -> int:
    """Modbus requests the driver has sent (its transport counts them)."""
    return driver._transport._modbus.requests  # type: ignore[union-attr]


def test_one_request_reads_the_area_and_one_writes_it():
    """Every published type reads back exactly in one request; a write sends the whole output area in one request."""
    settings = modbus_settings(free_port())
    written: list[tuple[str, float]] = []

    async def scenario() -> tuple[dict[str, float], int, int]:
        server, driver = await served(settings, written=written)
        try:
            values = await driver.read(list(INPUTS))
            after_read = requests(driver)
            await driver.write({"out:0:int32": -70000.0, "out:8:float32": 2.5, "out:6.0": 1.0})
            return values, after_read, requests(driver) - after_read
        finally:
            await shut(server, driver)

    values, reads, writes = asyncio.run(scenario())
    assert values == INPUTS
    assert (reads, writes) == (1, 1)
    assert dict(written) == {
        "out:0:int32": -70000.0,
        "out:4:int16": 0.0,
        "out:6.0": 1.0,
        "out:8:float32": 2.5,
    }


def plain_master(settings: GatewaySettings) -> ModbusDriver:
    """A plain Modbus master on the gateway's port (not yet open)."""
    return ModbusDriver(
        ModbusSettings(host="127.0.0.1", port=settings.port), now=time.monotonic, base_dir=Path()
    )


def test_a_plain_modbus_master_sees_the_big_endian_image():
    """Independent check of the layout: a plain Modbus master reads the output area at holding 100.. (ABCD)."""
    settings = modbus_settings(free_port())

    async def scenario() -> dict[str, float]:
        server, driver = await served(settings)
        plain = plain_master(settings)
        try:
            await driver.write({"out:0:int32": -70000.0, "out:4:int16": -3.0})
            await plain.open()
            return await plain.read(["holding:100:int32", "holding:102:int16", "input:10:int16"])
        finally:
            await plain.close()
            await shut(server, driver)

    assert asyncio.run(scenario()) == {
        "holding:100:int32": -70000.0,
        "holding:102:int16": -3.0,
        "input:10:int16": -1234.0,
    }


def test_an_output_address_reads_back_what_the_gateway_holds():
    """An out: address reads the gateway's output area, not the driver's copy: another master's change shows."""
    settings = modbus_settings(free_port())

    async def scenario() -> dict[str, float]:
        server, driver = await served(settings)
        other = plain_master(settings)
        try:
            await driver.write({"out:0:int32": -70000.0})
            await other.open()
            await other.write({"holding:100:int32": 25.0})  # e.g. the gateway restarted, reset
            return await driver.read(["out:0:int32", "in:0:int16"])
        finally:
            await other.close()
            await shut(server, driver)

    assert asyncio.run(scenario()) == {"out:0:int32": 25.0, "in:0:int16": -1234.0}
    assert GatewayDriver.reads_back(settings)


def test_dp_side_down_and_frozen_gateway():
    """Over Modbus too: a clear ok bit is a DriverProtocolError, a live bit that stops toggling a DriverTimeoutError."""
    settings = modbus_settings(free_port())

    async def scenario() -> None:
        server, driver = await served(settings)
        try:
            server.set_dp_down()
            with pytest.raises(DriverProtocolError, match="Profibus side not in data exchange"):
                await driver.read(["in:0:int16"])
            server.set_dp_down(False)
            assert await driver.read(["in:0:int16"]) == {"in:0:int16": -1234.0}
            server.freeze()
            frozen = time.monotonic()
            with pytest.raises(DriverTimeoutError, match="frozen"):  # noqa: PT012 - polls
                while time.monotonic() - frozen < 60.0:  # a hang guard: the read raises first
                    await driver.read(["in:0:int16"])
                    await asyncio.sleep(0.05)
            assert time.monotonic() - frozen >= settings.live_timeout_s
            server.freeze(False)
            assert await driver.read(["in:0:int16"]) == {"in:0:int16": -1234.0}
        finally:
            await shut(server, driver)

    asyncio.run(scenario())


def test_link_recovers_after_a_gateway_restart():
    """Through the DriverLink, ticks go on while the gateway is off; I/O returns within 5 s of its restart."""
    settings = modbus_settings(free_port())
    server = make_server(settings)
    clock = VirtualClock()  # the backoff's clock: the retries counted, not the machine's speed
    # timeout_s ends a hung read only (a stopped gateway refuses at once): on a busy host a
    # short one would time out a good read and count a second reconnect.
    link = DriverLink("gw", make_driver(settings), clock, timeout_s=10.0, backoff_min_s=0.1)

    async def scenario() -> float:
        await server.start()
        await link.open()
        assert await link.write({"out:0:int32": 7.0}) is True
        await server.stop()
        for _ in range(3):
            assert await link.read(["in:0:int16"]) == {}
            assert await link.write({"out:0:int32": 1.0}) is False
            await asyncio.sleep(0.05)
        await server.start()
        resumed_s = await seconds_until_read(link, clock, ["in:0:int16", "out:0:int32"])
        assert await link.write({"out:4:int16": 2.0}) is True
        await link.close()
        await server.stop()
        return resumed_s

    assert asyncio.run(scenario()) < 5.0
    assert link.reconnects == 1 and link.faults == 1
    # Published inputs and the output image survive the restart.
    assert bytes(server.output_image[4:6]) == (2).to_bytes(2, "big")


def test_settings_limits():
    """Over Modbus, areas are whole registers and fit one request; a host is needed."""
    with pytest.raises(ValueError, match="must be even"):
        modbus_settings(502, input_bytes=31)
    with pytest.raises(ValueError, match="at most 246"):
        modbus_settings(502, output_bytes=248)
    with pytest.raises(ValueError, match="needs 'host'"):
        GatewaySettings(input_bytes=8)


CONFIG = """
schema: compd.config/1
model: bundled:example_gated_arx.yaml
drivers:
  gw:
    type: profibus_gateway
    settings: SETTINGS
signals:
  T_spindle_degC: {driver: gw, address: "SIGNAL", unit: degC}
  T_shopfloor_degC: {driver: gw, address: "in:2:int16", unit: degC}
  spindle_speed_rpm: {driver: gw, address: "in:16:uint16", unit: rpm}
outputs:
  Y: {model_output: disp_y_um, driver: gw, address: "OUTPUT", max_offset_um: 50, max_rate_um_per_s: 1}
"""
MODBUS = "{host: 127.0.0.1, input_bytes: 32, output_bytes: 16, output_live: {offset: 7, bit: 7}}"
CAN = "{transport: can, channel: can0, input_bytes: 32, output_bytes: 16}"


@pytest.mark.parametrize(
    ("settings", "signal", "output", "message"),
    [
        (MODBUS, "in:0:int33", "out:0:int32", "unknown type 'int33'"),
        (MODBUS, "in:30:int32", "out:0:int32", "outside the in area of 32 bytes"),
        (MODBUS, "in:0:int16", "in:4:int32", "the input area cannot be written"),
        (MODBUS, "in:0:int16", "out:14:int32", "outside the out area of 16 bytes"),
        (MODBUS, "in:0:int16", "out:4:int32", "overlaps compd's live bit out:7.7"),
        (MODBUS, "in:0", "out:0:int32:bytes=little", "unknown or repeated option 'bytes'"),
        (MODBUS, "in:0:bool", "out:0:int32", "a bool is one bit"),
        (CAN, "in:6:int32", "out:0:int32", "straddles frames 0 "),
        (CAN, "in:0:int16", "out:4:float64", "straddles frames 0 "),
    ],
)
def test_bad_address_is_a_config_error(tmp_path, settings, signal, output, message):
    """check-config rejects bad grammar, addresses outside the areas, writes to in:, the live bit, straddled frames."""
    text = CONFIG.replace("SETTINGS", settings).replace("SIGNAL", signal)
    with pytest.raises(ConfigFileError, match=message) as raised:
        parse_config(text.replace("OUTPUT", output), tmp_path / "c.yaml")
    bad_output = signal in ("in:0:int16", "in:0")
    where = "outputs.Y.address" if bad_output else "signals.T_spindle_degC.address"
    assert where in str(raised.value)
    assert "Write it as AREA:OFFSET" in str(raised.value)


def test_good_addresses_pass_the_config(tmp_path):
    """The same config with addresses that fit passes, on both transports (CAN: int32 at byte 8, a frame of its own)."""
    for settings in (MODBUS, CAN):
        text = CONFIG.replace("SETTINGS", settings).replace("SIGNAL", "in:4:float32")
        parse_config(text.replace("OUTPUT", "out:8:int32"), tmp_path / "c.yaml")


class TestModbusGatewayContract(DriverContract):
    """The gateway driver over Modbus TCP passes the driver contract."""

    @pytest.fixture
    def setup(self) -> Iterator[ContractSetup]:
        port = free_port()
        gateway = ThreadedGateway(make_server(modbus_settings(port)))
        gateway.start()
        proxy = TcpProxy(port)
        driver = make_driver(modbus_settings(proxy.port))
        yield ContractSetup(
            driver=driver,
            readable=("in:0:int16", "in:4:float32", "in:14.2", "out:0:int32"),
            writable="out:0:int32",
            missing="in:9000:int16",
            break_connection=proxy.cut,
        )
        proxy.cut()
        with contextlib.suppress(Exception):
            asyncio.run(driver.close())
        gateway.close()


def test_outputs_list_is_checked():
    """The simulated gateway refuses an output address in the input area, naming it."""
    with pytest.raises(ValueError, match="output address 'in:0:int16'"):
        GatewayServer(
            modbus_settings(502),
            inputs=[],
            outputs=["in:0:int16"],
            on_write=lambda a, v: None,
            base_dir=Path(),
        )
