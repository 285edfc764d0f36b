"""The Profibus gateway driver over CAN (CANopen PDOs, raw frames) against the simulated gateway on a virtual bus."""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any, ClassVar

import can
import pytest
import yaml
from hypothesis import given
from hypothesis import settings as settings_
from hypothesis import strategies as st

from compd.drivers.gateway.driver import GatewayDriver, GatewaySettings
from compd.drivers.registry import load_driver_type
from compd.errors import DriverError, DriverProtocolError, DriverTimeoutError
from compd.service.loop.clock import VirtualClock
from compd.service.loop.links import DriverLink
from compd.sim.plc.gateway import GatewayServer
from tests.reconnect import seconds_until_read

from .contract import ContractSetup, DriverContract
from .gateway_setup import (
    INPUTS,
    OUTPUTS,
    ThreadedGateway,
    can_settings,
    channel_name,
    make_driver,
    make_server,
)

RAW = {"protocol": "raw", "input_ids": [0x301, 0x302, 0x303, 0x304], "output_ids": [0x311, 0x312]}


async def served(settings: GatewaySettings, **options) -> tuple[GatewayServer, GatewayDriver]:
    """A started gateway and an open driver on one loop, as in the simulated machine."""
    server = make_server(settings, options.pop("written", None), **options)
    await server.start()
    driver = make_driver(settings)
    await driver.open()
    return server, driver


async def raised(driver: GatewayDriver, within_s: float = 30.0) -> BaseException:
    """The first exception a read raises, polling for up to ``within_s`` (a loaded machine is slow)."""
    deadline = time.monotonic() + within_s
    while time.monotonic() < deadline:
        try:
            await driver.read(["in:0:int16"])
        except Exception as exc:
            return exc
        await asyncio.sleep(0.02)
    raise AssertionError(f"no error within {within_s} s")


async def recovered(driver: GatewayDriver, within_s: float = 30.0) -> dict[str, float]:
    """The first read that succeeds, polling for up to ``within_s``."""
    deadline = time.monotonic() + within_s
    while True:
        try:
            return await driver.read(["in:0:int16"])
        except Exception:
            if time.monotonic() > deadline:
                raise
        await asyncio.sleep(0.02)


async def shut(server: GatewayServer, driver: GatewayDriver) -> None:
    await driver.close()
    await server.stop()


def test_registered():
    """The driver is registered as 'profibus_gateway'."""
    assert load_driver_type("profibus_gateway") is GatewayDriver


@pytest.mark.parametrize("protocol", ["canopen", "raw", "canopen sync"])
def test_reads_every_type_and_writes_the_output_area(protocol):
    """Every published type reads back exactly; a write sends the whole output area, reported per address."""
    changes = RAW if protocol == "raw" else {"sync": protocol.endswith("sync")}
    settings = can_settings(channel_name(), **changes)
    written: list[tuple[str, float]] = []

    async def scenario() -> tuple[dict[str, float], dict[str, float]]:
        server, driver = await served(settings, written=written)
        try:
            values = await driver.read(list(INPUTS))
            await driver.write({"out:0:int32": -70000.0, "out:8:float32": 2.5, "out:6.0": 1.0})
            for _ in range(100):
                if len(written) >= 4:
                    break
                await asyncio.sleep(0.005)
            return values, await driver.read(list(OUTPUTS))
        finally:
            await shut(server, driver)

    values, outputs = asyncio.run(scenario())
    assert values == INPUTS
    expected = {"out:0:int32": -70000.0, "out:4:int16": 0.0, "out:6.0": 1.0, "out:8:float32": 2.5}
    assert outputs == expected
    assert dict(written) == expected


def test_pdo_ids_and_little_endian_layout():
    """CANopen: TPDOn = 0x180 + 0x100(n-1) + node, RPDOn = 0x200 + ...; bytes little-endian per the setting."""
    settings = can_settings(channel_name())
    assert settings.can_ids("in") == (0x185, 0x285, 0x385, 0x485)
    assert settings.can_ids("out") == (0x205, 0x305)

    async def scenario() -> list[can.Message]:
        server = make_server(settings)
        await server.start()
        bus = can.Bus(interface="virtual", channel=settings.channel)
        try:
            seen: dict[int, can.Message] = {}
            deadline = time.monotonic() + 30  # a hang guard: the loop ends at the 4th frame
            while len(seen) < 4 and time.monotonic() < deadline:
                msg = await asyncio.to_thread(bus.recv, 0.1)
                if msg is not None:
                    seen[msg.arbitration_id] = msg
            return [seen[i] for i in sorted(seen)]
        finally:
            bus.shutdown()
            await server.stop()

    frames = asyncio.run(scenario())
    assert [f.arbitration_id for f in frames] == [0x185, 0x285, 0x385, 0x485]
    assert all(f.dlc == 8 for f in frames)
    assert bytes(frames[0].data[:2]) == (-1234).to_bytes(2, "little", signed=True)
    assert bytes(frames[1].data[:4]) == (-123456789).to_bytes(4, "little", signed=True)


def test_sync_reads_the_cycle_it_triggered():
    """With sync: true each read sends one SYNC and gets that cycle's TPDOs: a value published just before is read."""
    settings = can_settings(channel_name(), sync=True)

    async def scenario() -> tuple[list[float], int]:
        server, driver = await served(settings)
        try:
            seen = []
            cycles = server.cycles
            for value in (1.0, 2.0, 3.0):
                server.publish({"in:0:int16": value})
                seen.append((await driver.read(["in:0:int16"]))["in:0:int16"])
            return seen, server.cycles - cycles
        finally:
            await shut(server, driver)

    assert asyncio.run(scenario()) == ([1.0, 2.0, 3.0], 3)


def test_silent_gateway_goes_stale_then_times_out():
    """A stopped gateway's values drop out after stale_s; after frame_timeout_s reads and writes time out."""
    settings = can_settings(channel_name(), stale_s=0.2, frame_timeout_s=0.6)

    async def scenario() -> None:
        server, driver = await served(settings)
        try:
            await server.stop()
            stopped = time.monotonic()
            await asyncio.sleep(settings.stale_s + 0.05)
            assert await driver.read(["in:0:int16", "out:0:int32"]) == {"out:0:int32": 0.0}
            await asyncio.sleep(settings.frame_timeout_s + 0.05 - (time.monotonic() - stopped))
            with pytest.raises(DriverTimeoutError, match="no frame"):
                await driver.read(["in:0:int16"])
            with pytest.raises(DriverTimeoutError, match="not written"):
                await driver.write({"out:0:int32": 1.0})
        finally:
            await shut(server, driver)

    asyncio.run(scenario())


def test_dp_side_down_and_frozen_gateway():
    """A clear ok bit is a DriverProtocolError (data exchange); a live bit that stops toggling a timeout."""
    settings = can_settings(channel_name())

    async def scenario() -> None:
        server, driver = await served(settings)
        try:
            server.set_dp_down()
            error = await raised(driver)
            assert isinstance(error, DriverProtocolError)
            assert "Profibus side not in data exchange" in str(error)
            server.set_dp_down(False)
            assert await recovered(driver) == {"in:0:int16": -1234.0}
            server.freeze()
            frozen = time.monotonic()
            error = await raised(driver)
            assert isinstance(error, DriverTimeoutError) and "frozen" in str(error)
            assert (
                time.monotonic() - frozen >= settings.live_timeout_s - 0.1
            )  # last toggle was before
            server.freeze(False)
            assert await recovered(driver) == {"in:0:int16": -1234.0}
        finally:
            await shut(server, driver)

    asyncio.run(scenario())


def test_output_live_bit_toggles_on_every_write():
    """compd's live bit (output_live) flips with each write, and reaches the PLC."""
    settings = can_settings(channel_name())

    async def scenario() -> list[float]:
        server, driver = await served(settings)
        try:
            bits = []
            for _ in range(3):
                await driver.write({"out:0:int32": 1.0})
                bits.append((await driver.read(["out:7.7"]))["out:7.7"])
            await asyncio.sleep(0.05)
            bits.append(float(server.output_image[7] >> 7))
            return bits
        finally:
            await shut(server, driver)

    assert asyncio.run(scenario()) == [1.0, 0.0, 1.0, 1.0]


def test_malformed_frame_is_a_protocol_error():
    """A TPDO with the wrong length is not used; the next read names it; reads then go on."""
    settings = can_settings(channel_name())

    async def scenario() -> None:
        server, driver = await served(settings)
        try:
            server.send_malformed()
            error = await raised(driver)
            assert isinstance(error, DriverProtocolError)
            assert "0x185 carried 3 bytes, expected 8" in str(error)
            assert await driver.read(["in:0:int16"]) == {"in:0:int16": -1234.0}
        finally:
            await shut(server, driver)

    asyncio.run(scenario())


def test_out_of_range_write_sends_nothing():
    """A value that does not fit its type raises DriverProtocolError and no frame of the batch is sent."""
    settings = can_settings(channel_name())
    written: list[tuple[str, float]] = []

    async def scenario() -> None:
        server, driver = await served(settings, written=written)
        try:
            with pytest.raises(DriverProtocolError, match="does not fit int16"):
                await driver.write({"out:0:int32": 5.0, "out:4:int16": 40000.0})
            with pytest.raises(DriverProtocolError, match="input area cannot be written"):
                await driver.write({"in:0:int16": 1.0})
            await asyncio.sleep(0.05)
        finally:
            await shut(server, driver)

    asyncio.run(scenario())
    assert written == []


def test_settings_limits():
    """CANopen carries at most 4 PDOs each way; raw needs one id per 8 bytes; can needs a channel."""
    with pytest.raises(ValueError, match="at most 4 PDOs"):
        can_settings("x", input_bytes=40)
    with pytest.raises(ValueError, match="needs 4 input_ids"):
        can_settings("x", protocol="raw", input_ids=[0x301], output_ids=[0x311, 0x312])
    with pytest.raises(ValueError, match=r"needs 'channel'"):
        GatewaySettings(transport="can", input_bytes=8)
    with pytest.raises(ValueError, match=r"status\.offset must be below"):
        can_settings("x", status={"offset": 40, "live_bit": 0})


def test_link_recovers_after_a_gateway_restart():
    """Through the DriverLink, ticks go on while the gateway is off; values return within 5 s of its restart."""
    settings = can_settings(channel_name())
    server = make_server(settings)
    clock = VirtualClock()  # the backoff's clock: the retries counted, not the machine's speed
    link = DriverLink("gw", make_driver(settings), clock, timeout_s=0.5, backoff_min_s=0.1)

    async def scenario() -> float:
        await server.start()
        await link.open()
        assert await link.read(["in:0:int16"]) == {"in:0:int16": -1234.0}
        await server.stop()
        deadline = time.monotonic() + 30  # a hang guard
        while link.up:  # stale, then timed out: the link goes down
            assert time.monotonic() < deadline
            await link.read(["in:0:int16"])
            await asyncio.sleep(0.05)
        assert await link.read(["in:0:int16"]) == {}
        for _ in range(3):
            assert await link.write({"out:0:int32": 1.0}) is False
            await asyncio.sleep(0.05)
        await server.start()
        resumed_s = await seconds_until_read(link, clock, ["in:0:int16"])
        assert await link.write({"out:0:int32": 2.0}) is True
        await link.close()
        await server.stop()
        return resumed_s

    assert asyncio.run(scenario()) < 5.0
    assert link.reconnects == 1 and link.faults == 1


def _vcan0_available() -> str | None:
    try:
        bus = can.Bus(interface="socketcan", channel="vcan0")
    except Exception as exc:
        return f"SocketCAN vcan0 not available ({type(exc).__name__}: {exc})"
    bus.shutdown()
    return None


def test_socketcan_vcan0():
    """On SocketCAN (vcan0, where the kernel has it) the driver reads and writes through a file-descriptor reader."""
    reason = _vcan0_available()
    if reason is not None:
        pytest.skip(reason)
    settings = can_settings("vcan0", interface="socketcan", node_id=9)
    written: list[tuple[str, float]] = []

    async def scenario() -> dict[str, float]:
        server, driver = await served(settings, written=written)
        try:
            await driver.write({"out:0:int32": 42.0})
            await asyncio.sleep(0.05)
            return await driver.read(list(INPUTS))
        finally:
            await shut(server, driver)

    assert asyncio.run(scenario()) == INPUTS
    assert ("out:0:int32", 42.0) in written


class _CanContract(DriverContract):
    changes: ClassVar[dict[str, object]] = {}

    @pytest.fixture
    def setup(self) -> Iterator[ContractSetup]:
        settings = can_settings(channel_name(), **self.changes)
        gateway = ThreadedGateway(make_server(settings))
        gateway.start()
        driver = make_driver(settings)

        def break_connection() -> None:
            # The gateway goes silent; a CAN read learns it when its frames age out.
            gateway.stop()
            time.sleep(settings.frame_timeout_s + 0.05)

        yield ContractSetup(
            driver=driver,
            readable=("in:0:int16", "in:4:float32", "in:14.2", "out:0:int32"),
            writable="out:0:int32",
            missing="in:9000:int16",
            break_connection=break_connection,
        )
        with contextlib.suppress(Exception):
            asyncio.run(driver.close())
        gateway.close()


class TestCanopenContract(_CanContract):
    """The gateway driver over CANopen PDOs passes the driver contract."""


class TestRawCanContract(_CanContract):
    """The gateway driver over raw CAN frames passes the driver contract."""

    changes = RAW


def test_unknown_bitrate_option_is_a_settings_error():
    """Settings keys are checked: a typo is an error, not ignored."""
    with pytest.raises(ValueError, match="bitrat"):
        GatewaySettings.model_validate(
            {"transport": "can", "channel": "can0", "input_bytes": 8, "bitrat": 500000}
        )


def test_server_rejects_addresses_the_gateway_cannot_have():
    """The simulated gateway checks its addresses like the driver: a straddling int32 is refused."""
    with pytest.raises(ValueError, match="straddles frames 0 "):
        GatewayServer(
            can_settings("x"),
            inputs=["in:6:int32"],
            outputs=[],
            on_write=lambda a, v: None,
            base_dir=Path(),
        )


def test_the_commented_example_config_is_valid():
    """The commented-out gateway driver in config/compd.example.yaml validates once uncommented."""
    text = (Path(__file__).parents[2] / "config" / "compd.example.yaml").read_text()
    block = text[text.index("  # dp:") : text.index("  # Gateway addresses")]
    doc = yaml.safe_load("\n".join(line.replace("  # ", "  ", 1) for line in block.splitlines()))
    assert doc["dp"]["type"] == "profibus_gateway"
    settings = GatewaySettings.model_validate(doc["dp"]["settings"])
    assert settings.can_ids("in") == (0x185, 0x285, 0x385, 0x485)
    for address in ("in:0:int16", "in:8:float32:word=big", "in:30.2"):
        GatewayDriver.validate_address(address, writable=False, settings=settings)
    GatewayDriver.validate_address("out:0:int32", writable=True, settings=settings)


@st.composite
def _malformed(draw: st.DrawFn, ids: tuple[int, ...]) -> can.Message:
    """A good input frame with one thing wrong: its data's length, its DLC, a flag, or its id."""
    fields: dict[str, Any] = {
        "arbitration_id": draw(st.sampled_from(ids)),
        "data": draw(st.binary(min_size=8, max_size=8)),
        "dlc": 8,
        "is_extended_id": False,
    }
    wrong = draw(
        st.sampled_from(
            ["data", "dlc", "is_extended_id", "is_remote_frame", "is_error_frame", "arbitration_id"]
        )
    )
    fields[wrong] = draw(
        {
            "data": st.binary(max_size=64).filter(lambda data: len(data) != 8),
            "dlc": st.integers(0, 15).filter(lambda dlc: dlc != 8),
            "arbitration_id": st.integers(0, 0x7FF).filter(lambda i: i not in ids),
        }.get(wrong, st.just(True))
    )
    return can.Message(**fields, check=False)


def test_malformed_frames_never_shift_the_image():
    """Whatever malformed frames arrive between good ones, a read gives the published values or raises DriverError."""
    settings = can_settings(channel_name(), status=None)
    ids = settings.can_ids("in")
    image = bytes(make_server(settings).input_image)  # INPUTS as the gateway encodes them
    good = [
        can.Message(arbitration_id=i, data=image[8 * k : 8 * k + 8], is_extended_id=False)
        for k, i in enumerate(ids)
    ]
    gateway = can.Bus(interface="virtual", channel=settings.channel)
    driver = make_driver(settings)

    async def delivered(frames: list[can.Message]) -> None:
        """Send ``frames`` then a good second frame, and wait until the driver has taken that one in."""
        counts = driver._transport.counts  # the driver's own count of frames used, per frame
        before = counts[1]
        for msg in [*frames, good[1]]:
            gateway.send(msg)
        deadline = time.monotonic() + 10  # a hang guard only
        while counts[1] == before:
            assert time.monotonic() < deadline, "the driver took in no frame"
            await asyncio.sleep(0.001)

    async def opened() -> None:
        opening = asyncio.ensure_future(driver.open())
        while not opening.done():  # open waits for one whole input image
            for msg in good:
                gateway.send(msg)
            await asyncio.sleep(0.01)
        await opening

    with asyncio.Runner() as runner:
        runner.run(opened())

        @settings_(max_examples=40, deadline=None)
        @given(frames=st.lists(_malformed(ids), min_size=1, max_size=4))
        def check(frames: list[can.Message]) -> None:
            runner.run(delivered([*good, *frames]))
            for _ in range(2):  # the first read may name a malformed frame, the next goes on
                try:
                    values = runner.run(driver.read(list(INPUTS)))
                except DriverError:
                    continue
                assert values == {a: v for a, v in INPUTS.items() if a in values}

        try:
            check()
        finally:
            runner.run(driver.close())
            gateway.shutdown()
