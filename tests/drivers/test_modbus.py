"""The Modbus driver over TCP against real pymodbus servers on 127.0.0.1, and Debian's mbpoll as a peer."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import re
import shutil
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from structlog.testing import capture_logs

from compd.drivers.modbus.driver import ModbusDriver
from compd.drivers.modbus.settings import ModbusSettings
from compd.drivers.registry import load_driver_type
from compd.errors import (
    ConfigFileError,
    DriverDisconnectedError,
    DriverProtocolError,
    DriverTimeoutError,
)
from compd.service.config.loading import parse_config
from compd.service.daemon import Service
from compd.service.loop.clock import RealClock, VirtualClock
from compd.service.loop.compensator import TickRecord
from compd.service.loop.links import DriverLink
from compd.service.loop.safety import Flag
from tests.reconnect import seconds_until_read

from ..service.daemon_setup import write_config
from .contract import ContractSetup, DriverContract
from .modbus_server import (
    INPUTS,
    READONLY_START,
    ServerThread,
    TcpProxy,
    free_port,
    tcp_server,
)

#: Real-time bound of the reconnect loops below: a guard against a hang, not a speed target (the
#: links reconnect within 0.02-0.1 s; a busy CI machine must not fail them).
HANG_GUARD_S = 60.0


@pytest.fixture(scope="module")
def server() -> Iterator[int]:
    """One TCP server for the module; yields its port."""
    port = free_port()
    thread = tcp_server(port)
    thread.start()
    yield port
    thread.stop()


def make_driver(port: int, **settings) -> ModbusDriver:
    settings.setdefault("request_timeout_s", 0.5)
    return ModbusDriver(
        ModbusSettings(host="127.0.0.1", port=port, **settings), now=time.monotonic, base_dir=Path()
    )


def run(driver: ModbusDriver, *calls):
    """Open the driver, await each (method, argument) call in turn, close; return the results."""

    async def scenario():
        await driver.open()
        try:
            return [await getattr(driver, name)(arg) for name, arg in calls]
        finally:
            await driver.close()

    return asyncio.run(scenario())


def test_registered():
    """The driver is registered as 'modbus'."""
    assert load_driver_type("modbus") is ModbusDriver


def test_reads_every_type_and_order_in_one_request(server):
    """Contiguous input registers of mixed types and orders decode exactly, in one request."""
    driver = make_driver(server)
    (values,) = run(driver, ("read", list(INPUTS)))
    assert values == pytest.approx(INPUTS)
    assert driver.requests == 1


def test_bits_and_gaps(server):
    """Coils and discrete inputs read as 0.0/1.0; a gap between points splits the request."""
    driver = make_driver(server)
    (values,) = run(
        driver,
        ("read", ["discrete:0", "discrete:1", "discrete:2", "input:0:int16", "input:4:uint32"]),
    )
    assert values == {
        "discrete:0": 1.0,
        "discrete:1": 0.0,
        "discrete:2": 1.0,
        "input:0:int16": -1234.0,
        "input:4:uint32": 3e9,
    }
    assert driver.requests == 3


def test_write_round_trip(server):
    """Offsets and bits written are read back: int32 in 0.1 um, float32 word-swapped, a coil."""
    driver = make_driver(server)
    written = {"holding:10:int32": -12345.0, "holding:12:float32:word=little": 2.5, "coil:3": 1.0}
    _, values = run(driver, ("write", written), ("read", list(written)))
    assert values == written
    assert driver.requests == 1 + 1 + 2  # contiguous holding registers: one write, one read


def test_out_of_range_write_sends_nothing(server):
    """A value that does not fit its type raises DriverProtocolError and no value of the batch is written."""
    driver = make_driver(server)
    run(driver, ("write", {"holding:20:int16": 5.0}))
    with pytest.raises(DriverProtocolError, match="does not fit int16"):
        run(driver, ("write", {"holding:20:int16": 6.0, "holding:21:int16": 40000.0}))
    assert run(driver, ("read", ["holding:20:int16"]))[0] == {"holding:20:int16": 5.0}


def test_nan_from_the_device_is_passed_on_for_the_checks(server):
    """A float32 NaN in the PLC reads as NaN (the loop's signal checks reject it), not as an exception."""
    driver = make_driver(server)
    raw = {"holding:70": 0x7FC0, "holding:71": 0x0000}  # float32 quiet NaN, ABCD
    _, values = run(driver, ("write", raw), ("read", ["holding:70:float32"]))
    assert math.isnan(values["holding:70:float32"])


def test_rejected_write_is_a_protocol_error(server):
    """A write the server refuses (read-only registers) raises DriverProtocolError with the exception code."""
    driver = make_driver(server)
    with pytest.raises(DriverProtocolError, match="refused"):
        run(driver, ("write", {f"holding:{READONLY_START}": 1.0}))


def test_bad_address_is_a_config_error(tmp_path):
    """A malformed address, or an output on a read-only table, fails config validation naming the key."""
    base = """
schema: compd.config/1
model: bundled:example_gated_arx.yaml
drivers:
  plc: {type: modbus, settings: {host: 127.0.0.1}}
signals:
  T_spindle_degC: {driver: plc, address: "holding:100:int33", unit: degC}
  T_shopfloor_degC: {driver: plc, address: "input:1:int16", unit: degC}
  spindle_speed_rpm: {driver: plc, address: "input:2", unit: rpm}
outputs:
  Y: {model_output: disp_y_um, driver: plc, address: "OUT", max_offset_um: 50, max_rate_um_per_s: 1}
"""
    with pytest.raises(ConfigFileError, match="int33") as raised:
        parse_config(base.replace("OUT", "holding:10:int32"), tmp_path / "c.yaml")
    assert "signals.T_spindle_degC.address" in str(raised.value)
    good = base.replace("int33", "int32")
    with pytest.raises(ConfigFileError, match="cannot be written"):
        parse_config(good.replace("OUT", "input:10:int32"), tmp_path / "c.yaml")
    parse_config(good.replace("OUT", "holding:10:int32"), tmp_path / "c.yaml")


def test_settings_need_a_host_or_port():
    """tcp needs host and rtu needs serial_port."""
    with pytest.raises(ValueError, match="needs 'host'"):
        ModbusSettings()
    with pytest.raises(ValueError, match="needs 'serial_port'"):
        ModbusSettings(transport="rtu")


def test_server_stopped_and_restarted():
    """With the server gone, read raises DriverDisconnectedError; within 5 s of its return a new open() works."""
    port = free_port()
    thread = tcp_server(port)
    thread.start()
    driver = make_driver(port)

    async def scenario() -> float:
        await driver.open()
        assert await driver.read(["input:0:int16"]) == {"input:0:int16": -1234.0}
        thread.stop()
        with pytest.raises(DriverDisconnectedError):
            await driver.read(["input:0:int16"])
        with pytest.raises(DriverDisconnectedError):
            await driver.open()
        thread.start()
        back = time.monotonic()
        retries = 0  # counted, not timed: a busy host makes each attempt slower, not more
        while True:
            try:
                await driver.open()
                break
            except DriverDisconnectedError:
                assert time.monotonic() - back < HANG_GUARD_S, "no reconnect: the link hangs"
                retries += 1
                await asyncio.sleep(0.1)
        assert await driver.read(["input:0:int16"]) == {"input:0:int16": -1234.0}
        await driver.close()
        return retries * 0.1

    try:
        assert asyncio.run(scenario()) < 5.0, "back within 5 s of retrying every 0.1 s"
    finally:
        thread.stop()


def test_link_keeps_ticking_and_reconnects():
    """Through the DriverLink, ticks go on while the server is gone and values return within 5 s of its return."""
    port = free_port()
    thread = tcp_server(port)
    thread.start()
    clock = VirtualClock()  # the backoff's clock: the retries counted, not the machine's speed
    # timeout_s ends a hung read only (a stopped server refuses at once): on a busy host a
    # short one would time out a good read and count a second reconnect.
    link = DriverLink("plc", make_driver(port), clock, timeout_s=10.0, backoff_min_s=0.1)

    async def scenario() -> float:
        await link.open()
        assert await link.read(["input:0:int16"]) == {"input:0:int16": -1234.0}
        thread.stop()
        for _ in range(5):  # ticks while the server is down: no values, no exception
            assert await link.read(["input:0:int16"]) == {}
            assert await link.write({"holding:0": 1.0}) is False
            await asyncio.sleep(0.05)
        thread.start()
        resumed_s = await seconds_until_read(link, clock, ["input:0:int16"])
        await link.close()
        return resumed_s

    try:
        assert asyncio.run(scenario()) < 5.0
        assert link.reconnects == 1 and link.faults == 1
    finally:
        thread.stop()


def link_to_new_server(**settings: object) -> tuple[DriverLink, ServerThread]:
    """A started server on a free port, and a link to it that reconnects within 0.02-0.1 s."""
    port = free_port()
    thread = tcp_server(port)
    thread.start()
    driver = make_driver(port, **settings)
    timeout_s = driver.settings.request_timeout_s + 0.2
    link = DriverLink(
        "plc", driver, RealClock(), timeout_s=timeout_s, backoff_min_s=0.02, backoff_max_s=0.1
    )
    return link, thread


def drop_and_restore(
    link: DriverLink, thread: ServerThread, drops: int
) -> tuple[list[dict], list[logging.LogRecord]]:
    """``drops`` times: ticks with the server gone, then until it answers; events and stdlib records."""

    async def scenario() -> None:
        await link.open()
        for _ in range(drops):
            assert await link.read(["input:0:int16"]) == {"input:0:int16": -1234.0}
            await asyncio.to_thread(thread.stop)
            for _ in range(4):  # ticks while the server is down: reads, writes, reconnects
                await link.read(["input:0:int16"])
                await link.write({"holding:0": 1.0})
                await asyncio.sleep(0.06)
            await asyncio.to_thread(thread.start)
            back = time.monotonic()
            while not await link.read(["input:0:int16"]):
                assert time.monotonic() - back < HANG_GUARD_S, "no reconnect: the link hangs"
                await asyncio.sleep(0.02)
        await link.close()

    records: list[logging.LogRecord] = []
    handler = logging.Handler(logging.DEBUG)
    handler.emit = records.append  # type: ignore[method-assign]
    logging.getLogger().addHandler(handler)
    try:
        with capture_logs() as events:
            asyncio.run(scenario())
    finally:
        logging.getLogger().removeHandler(handler)
        thread.stop()
    return events, records


def test_link_drops_log_one_error_each_and_no_pymodbus_dumps():
    """6 drops of a real server: 6 ERRORs, DEBUG in between, 6 INFO recoveries; pymodbus adds nothing above DEBUG."""
    link, thread = link_to_new_server(request_timeout_s=0.2)
    events, records = drop_and_restore(link, thread, drops=6)
    levels = [(e["log_level"], e["event"]) for e in events]
    assert [e for lvl, e in levels if lvl == "error"] == ["driver read failed"] * 6
    assert [e for lvl, e in levels if lvl == "info"] == ["driver connected"] + [
        "driver reconnected"
    ] * 6
    assert {lvl for lvl, _ in levels} <= {"error", "info", "debug"} and link.faults == 6
    assert [r for r in records if r.name.startswith("pymodbus") and r.levelno > logging.DEBUG] == []
    assert not any(">>>>>" in r.getMessage() for r in records)
    assert logging.getLogger("pymodbus").getEffectiveLevel() == logging.WARNING


def test_pymodbus_frame_dumps_never_reach_compds_debug_log(server):
    """At compd's DEBUG, with pymodbus's frame logger at DEBUG too, compd's log carries no frame hex dump."""
    root, frames = logging.getLogger(), logging.getLogger("pymodbus.logging")
    levels = root.level, frames.level
    root.setLevel(logging.DEBUG)
    frames.setLevel(logging.DEBUG)  # as a dictConfig or pymodbus's Log.setLevel would
    try:
        with capture_logs() as events:
            assert run(make_driver(server), ("read", ["input:0:int16"])) == [
                {"input:0:int16": -1234.0}
            ]
    finally:
        root.setLevel(levels[0])
        frames.setLevel(levels[1])
    assert [e for e in events if e["event"] == "pymodbus"] == []
    assert not any("0x" in str(e) for e in events)


def test_a_peer_that_connects_but_never_answers_is_one_fault():
    """A server that connects but never answers (another device id) is one ERROR, however often it reconnects."""
    link, thread = link_to_new_server(request_timeout_s=0.1, device_id=9)

    async def scenario() -> None:
        await link.open()
        started = time.monotonic()
        while link.reconnects < 4:
            assert time.monotonic() - started < HANG_GUARD_S, "the link did not reconnect: it hangs"
            assert await link.read(["input:0:int16"]) == {}
            await asyncio.sleep(0.02)
        await link.close()

    try:
        with capture_logs() as events:
            asyncio.run(scenario())
    finally:
        thread.stop()
    levels = [e["log_level"] for e in events]
    assert levels.count("error") == 1 and levels.count("info") == 1  # "driver connected" at first
    assert link.faults == 1 and link.reconnects >= 4


# Replies of a broken peer to any request (``header``: the request's 7-byte MBAP header).
BROKEN_PEERS = {
    # The PDU claims 9 data bytes and carries 2: pymodbus drops the connection
    # to resynchronise the stream, so the link reconnects.
    "truncated": (
        lambda header: header[:2] + b"\x00\x00\x00\x05" + header[6:7] + b"\x03\x09\x00\x01",
        DriverDisconnectedError,
    ),
    # A well-formed reply to another function (43): no registers in it.
    "wrong function": (
        lambda header: header[:2] + b"\x00\x00\x00\x03" + header[6:7] + b"\x2b\x01",
        DriverProtocolError,
    ),
    "silent": (lambda header: b"", DriverTimeoutError),
}


@pytest.mark.parametrize("peer", list(BROKEN_PEERS))
def test_broken_peer_is_a_driver_error(peer):
    """A truncated frame, a reply to another function and no reply are the DriverError of their kind."""
    reply, expected = BROKEN_PEERS[peer]

    async def broken_server(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        with contextlib.suppress(ConnectionError, asyncio.CancelledError):
            while request := await reader.read(260):
                writer.write(reply(request[:7]))
                await writer.drain()

    async def scenario() -> None:
        srv = await asyncio.start_server(broken_server, "127.0.0.1", 0)
        driver = make_driver(srv.sockets[0].getsockname()[1], request_timeout_s=0.2)
        await driver.open()
        try:
            with pytest.raises(expected):
                await driver.read(["holding:0:int32"])
        finally:
            await driver.close()
            srv.close()

    asyncio.run(scenario())


def test_mbpoll_reads_what_compd_wrote(server):
    """Debian's mbpoll, an independent Modbus master, reads compd's offsets at 1-based register numbers."""
    if shutil.which("mbpoll") is None:
        pytest.skip("mbpoll not installed: run .ci/install-system-packages")
    driver = make_driver(server)
    written = {"holding:40:int32": -12345.0, "holding:42:int32:word=little": 987654.0}
    run(driver, ("write", written))

    def mbpoll(*options: str) -> int:
        out = subprocess.run(
            ["mbpoll", "-1", "-p", str(server), *options, "127.0.0.1"],
            capture_output=True,
            text=True,
            timeout=10,
            check=True,
        ).stdout
        return int(re.search(r"^\[\d+\]:\s*(-?\d+)", out, re.MULTILINE).group(1))

    # Register 41 (1-based) is protocol address 40; -B: most significant word first.
    assert mbpoll("-t", "4:int", "-B", "-r", "41") == -12345
    # mbpoll's default 32-bit word order is least significant word first.
    assert mbpoll("-t", "4:int", "-r", "43") == 987654
    assert mbpoll("-t", "4", "-r", "41", "-c", "2") == 0xFFFF  # high word of -12345


def test_service_writes_offsets_to_the_plc_and_survives_its_restart(tmp_path, server):
    """The daemon writes int32 offsets (0.1 um), status and heartbeat to a PLC and resumes within 5 s of its restart."""
    port = free_port()
    plc = tcp_server(port)
    plc.start()
    on_plc = {"driver": "plc", "unit": "degC", "scale": 0.01}
    config = write_config(
        tmp_path,
        {
            "drivers": {
                "plc": {
                    "type": "modbus",
                    "settings": {"host": "127.0.0.1", "port": port, "request_timeout_s": 0.1},
                    "timeout_s": 0.2,
                    "reconnect_min_s": 0.5,
                    "reconnect_max_s": 2.0,
                }
            },
            "signals": {
                "T_spindle_degC": {**on_plc, "address": "input:10:int16"},
                "T_shopfloor_degC": {**on_plc, "address": "input:11:int16"},
                "spindle_speed_rpm": {"driver": "plc", "unit": "rpm", "address": "input:12"},
            },
            "outputs": {
                "Y": {
                    "driver": "plc",
                    "address": "holding:60:int32",
                    "encoding": {"type": "int", "scale": 10},
                }
            },
            "status": {
                "driver": "plc",
                "status_address": "holding:62",
                "heartbeat_address": "holding:63",
            },
        },
    )
    records: list[TickRecord] = []
    up: list[bool] = []
    # Real time, 5x fast (a tick every 0.2 s): reconnecting takes real I/O,
    # which a virtual clock would outrun.
    service = Service(config, clock=RealClock(5.0), control=False, background_saves=False)

    def on_tick(record: TickRecord) -> None:
        records.append(record)
        up.append(service.links["plc"].up)
        if len(records) == 8:
            plc.stop()
        elif len(records) == 12:
            plc.start()

    service.subscribe(on_tick)
    try:
        asyncio.run(service.run(duration_s=22.0))
        (registers,) = run(
            make_driver(port), ("read", ["holding:60:int32", "holding:62", "holding:63"])
        )
    finally:
        plc.stop()
    # A loaded machine may skip (count, not make up) a deadline: judge by service time.
    assert len(records) >= 18 and up[:8] == [True] * 8 and not any(up[9:12])
    back = up.index(True, 12)
    assert records[back].t_s - records[12].t_s <= 5.0
    assert all(r.written for r in records[back + 1 :])
    assert records[-1].values == pytest.approx(
        {"T_spindle_degC": 25.0, "T_shopfloor_degC": 22.0, "spindle_speed_rpm": 3000.0}
    )
    last = records[-1]
    assert registers == {
        "holding:60:int32": round(last.offsets_um["Y"] * 10),
        "holding:62": Flag.STOPPED,  # the last word written, at shutdown; level ok
        "holding:63": last.heartbeat,
    }
    assert service.links["plc"].reconnects == 1


class TestModbusTcpContract(DriverContract):
    """The Modbus driver over TCP passes the driver contract."""

    @pytest.fixture
    def setup(self, server) -> Iterator[ContractSetup]:
        # The contract breaks the connection: give each test a proxy to cut,
        # so the module's server stays up for the other tests.
        proxy = TcpProxy(server)
        driver = make_driver(proxy.port)
        yield ContractSetup(
            driver=driver,
            readable=("input:0:int16", "input:2:float32:word=little", "discrete:0"),
            writable="holding:30:int32",
            missing="holding:9000",
            break_connection=proxy.cut,
        )
        proxy.cut()
