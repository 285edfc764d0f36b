"""``compd read`` and ``compd probe`` against real peers: pymodbus, a secured asyncua, a pty scanner."""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import re
import select
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import serial
import yaml

from compd.drivers.modbus.driver import ModbusDriver
from compd.drivers.modbus.settings import ModbusSettings
from tests.clirun import compd_result as compd
from tests.drivers.instrument import PtyInstrument
from tests.drivers.modbus_server import free_port, running_tcp_server
from tests.drivers.test_modbus_rtu import pty_pair  # noqa: F401  (a fixture: socat's pty pair)

ROOT = Path(__file__).parents[2]
MODEL = ROOT / "config" / "simulated_model.yaml"


def points(stdout: str) -> dict[str, dict[str, Any]]:
    """The rows of the one JSON read printed, by point name."""
    (line,) = stdout.splitlines()
    return {p["name"]: p for p in json.loads(line)["points"]}


@pytest.fixture(scope="module")
def plc() -> Iterator[int]:
    """A pymodbus server on 127.0.0.1 (tests/drivers/modbus_server.py); yields its port."""
    with running_tcp_server() as port:
        yield port


def holding(port: int, address: str) -> float:
    """What the server holds at ``address``, read by a client of its own."""

    async def read() -> float:
        driver = ModbusDriver(
            ModbusSettings(host="127.0.0.1", port=port), now=time.monotonic, base_dir=Path(".")
        )
        await driver.open()
        try:
            return (await driver.read([address]))[address]
        finally:
            await driver.close()

    return asyncio.run(read())


def machine_config(directory: Path, port: int, **changes: Any) -> Path:
    """A daemon config on the test server: 25.00 and 22.00 degC in 0.01 degC, Z in 0.1 um, status."""
    doc: dict[str, Any] = {
        "schema": "compd.config/1",
        "model": str(MODEL),
        "drivers": {"plc": {"type": "modbus", "settings": {"host": "127.0.0.1", "port": port}}},
        "signals": {
            "T_spindle_degC": {
                "driver": "plc",
                "address": "input:10:int16",
                "scale": 0.01,
                "unit": "degC",
                "checks": {"min": 5, "max": 80},
            },
            "T_bed_degC": {
                "driver": "plc",
                "address": "input:11:int16",
                "scale": 0.01,
                "unit": "degC",
                "checks": {"min": 5, "max": 20},  # the server's 22.00 degC is above it
            },
        },
        "outputs": {
            "Z": {
                "model_output": "Z",
                "driver": "plc",
                "address": "holding:120:int32",
                "encoding": {"type": "int", "scale": 10},
                "max_offset_um": 100,
                "max_rate_um_per_s": 5,
            }
        },
        "status": {
            "driver": "plc",
            "status_address": "holding:122",
            "heartbeat_address": "holding:123",
        },
        "state": {"directory": str(directory / "state")},
        "recorder": {"enabled": False},
    }
    doc.update(changes)
    path = directory / "compd.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


# -- compd read ---------------------------------------------------------------


def test_read_shows_raw_registers_decoded_value_unit_and_the_checks_verdict(tmp_path, plc):
    """Each signal: its register as hex, the int16, the scaled degC; a value above max fails with exit 1."""
    write = compd("probe", "modbus", "--set", "host=127.0.0.1", "--set", f"port={plc}",
                  "holding:120:int32", "--write", "-25", "--yes")  # fmt: skip
    assert write[0] == 0, write
    code, out, err = compd("read", "--config", machine_config(tmp_path, plc), "--json")
    rows = points(out)
    spindle = rows["T_spindle_degC"]
    assert (spindle["raw"], spindle["device_value"], spindle["value"]) == ("0x09C4", 2500.0, 25.0)
    assert (spindle["unit"], spindle["health"], spindle["problem"]) == ("degC", "OK", "")
    bed = rows["T_bed_degC"]
    assert bed["value"] == 22.0 and bed["health"] == "FAULTED"
    assert bed["problem"] == "22 above max 20"
    offset = rows["offset Z"]  # read back: -25 counts of 0.1 um
    assert (offset["raw"], offset["value"], offset["unit"]) == ("0xFFFF 0xFFE7", -2.5, "um")
    assert {"status word", "heartbeat"} <= rows.keys()
    assert code == 1 and err == ""


def test_read_named_signals_only_and_the_table(tmp_path, plc):
    """Naming a signal reads only it; all good is exit 0; the table shows raw, value and unit."""
    code, out, _ = compd("read", "--config", machine_config(tmp_path, plc), "T_spindle_degC")
    assert code == 0
    assert "0x09C4" in out and "2500" in out and "degC" in out and "OK" in out
    assert "T_bed_degC" not in out and "offset Z" not in out


def test_read_an_unknown_name_is_refused_with_the_names_there_are(tmp_path, plc):
    code, _, err = compd("read", "--config", machine_config(tmp_path, plc), "T_nope")
    assert code == 2
    assert "no signal or output named 'T_nope'" in err and "T_spindle_degC" in err


def test_a_driver_that_cannot_connect_shows_its_error_on_each_row(tmp_path):
    """Nothing listening: every row says 'cannot connect', exit 1, no traceback."""
    with socket.socket() as held:  # bound, never listening: refused, and nobody else's meanwhile
        held.bind(("127.0.0.1", 0))
        config = machine_config(tmp_path, held.getsockname()[1])
        code, out, err = compd("read", "--config", config, "--json")
    rows = points(out)
    assert {r["health"] for r in rows.values()} == {"ERROR"}
    assert all("cannot connect" in r["problem"] for r in rows.values())
    assert code == 1 and "Traceback" not in out + err


def test_watch_reads_count_times_and_stops(tmp_path, plc):
    """--watch --count 3: three reads (JSON lines, numbered), then a clean exit."""
    config = machine_config(tmp_path, plc)
    code, out, _ = compd("read", "--config", config, "T_spindle_degC", "--watch", "--count", 3,
                         "--interval-s", 0.01, "--json")  # fmt: skip
    reads = [json.loads(line) for line in out.splitlines()]
    assert [r["read"] for r in reads] == [1, 2, 3]
    assert all(r["points"][0]["value"] == 25.0 for r in reads)
    assert code == 0


def test_the_bundled_replay_reads_through_the_fallback():
    """A driver without read_raw (the simulated one) shows read()'s float as its raw value."""
    code, out, _ = compd("read", "--config", "bundled:replay.yaml", "--json")
    row = points(out)["spindle_speed_rpm"]
    assert float(row["raw"]) == row["device_value"] == row["value"]
    assert code == 0


# -- compd probe --------------------------------------------------------------


def probe(port: int, *argv: object) -> tuple[int, str, str]:
    return compd("probe", "modbus", "--set", "host=127.0.0.1", "--set", f"port={port}", *argv)


def test_probe_reads_addresses_in_their_own_type(plc):
    """No config: registers and the value of each address's type, unscaled; a refused one is its error."""
    code, out, _ = probe(plc, "input:0:int16", "input:2:float32:word=little", "discrete:0",
                         "holding:9000", "--json")  # fmt: skip
    rows = points(out)
    assert (rows["input:0:int16"]["raw"], rows["input:0:int16"]["value"]) == ("0xFB2E", -1234.0)
    assert rows["input:2:float32:word=little"]["raw"] == "0x0000 0x41AC"
    assert rows["input:2:float32:word=little"]["value"] == 21.5
    assert (rows["discrete:0"]["raw"], rows["discrete:0"]["value"]) == ("1", 1.0)
    assert rows["holding:9000"]["health"] == "ERROR"
    assert "illegal data address" in rows["holding:9000"]["problem"]
    assert code == 1


def test_probe_write_without_a_terminal_or_yes_is_refused(plc):
    """Piped stdin, no --yes: nothing written, and the message says how to write from a script."""
    before = holding(plc, "holding:40:int32")
    code, _, err = probe(plc, "holding:40:int32", "--write", before + 7)
    assert code == 2 and "no terminal to confirm on" in err and "--yes" in err
    assert holding(plc, "holding:40:int32") == before


def test_probe_write_with_yes_lands_in_the_servers_registers(plc):
    """--yes: the raw int32 is written, read back and shown; another client sees it."""
    code, out, _ = probe(plc, "holding:42:int32", "--write", -70000, "--yes", "--json")
    assert code == 0
    assert points(out)["holding:42:int32"]["raw"] == "0xFFFE 0xEE90"
    assert holding(plc, "holding:42:int32") == -70000


def probe_on_terminal(port: int, address: str, value: int, answer: str) -> tuple[int, bytes]:
    """``compd probe ... ADDRESS --write VALUE`` on a pty, ``answer`` typed at its prompt: exit status, output."""
    main_fd, terminal = os.openpty()
    argv = ["probe", "modbus", "--set", "host=127.0.0.1", "--set", f"port={port}", address,
            "--write", str(value)]  # fmt: skip
    process = subprocess.Popen(
        [sys.executable, "-m", "compd.cli", *argv], stdin=terminal, stdout=terminal,
        stderr=terminal, cwd=ROOT,
    )  # fmt: skip
    os.close(terminal)
    seen = b""
    try:
        while b"to confirm" not in seen:
            ready, _, _ = select.select([main_fd], [], [], 60)
            assert ready, f"no prompt: {seen!r}"
            seen += os.read(main_fd, 4096)
        os.write(main_fd, answer.encode() + b"\n")
        with contextlib.suppress(OSError):  # the terminal closes with the process
            while chunk := os.read(main_fd, 4096):
                seen += chunk
        return process.wait(60), seen
    finally:
        process.kill()
        os.close(main_fd)


@pytest.mark.parametrize(("answer", "written"), [("holding:44", True), ("y", False)])
def test_probe_write_asks_on_a_terminal_for_the_address(plc, answer, written):
    """On a terminal the current value is shown, then only the address typed back writes."""
    before = holding(plc, "holding:44")
    code, seen = probe_on_terminal(plc, "holding:44", int(before) + 3, answer)
    assert code == (0 if written else 2), seen
    assert holding(plc, "holding:44") == (before + 3 if written else before)
    assert (b"not confirmed: nothing written" in seen) != written


def test_probe_write_shows_the_address_literally_never_as_an_emoji(plc):
    """holding:100:int32 is shown as typed in the prompt and the table, not as rich's :100: emoji."""
    code, seen = probe_on_terminal(plc, "holding:100:int32", 5, "holding:100:int32")
    assert code == 0, seen
    shown = re.sub(r"\x1b\[[0-9;]*m", "", seen.decode())  # the terminal's colours off
    assert "Write 5 to holding:100:int32" in shown and "(holding:100:int32) to confirm" in shown
    assert "\N{HUNDRED POINTS SYMBOL}" not in shown
    assert holding(plc, "holding:100:int32") == 5


def test_probe_refuses_bad_settings_and_addresses_before_connecting():
    """A misspelt setting or a bad address ends with exit 2 and the fix, nothing opened."""
    code, _, err = compd("probe", "modbus", "--set", "hots=10.0.0.1", "holding:1")
    assert code == 2 and "hots: unknown key 'hots'" in err and "--set KEY=VALUE" in err
    code, _, err = compd("probe", "modbus", "--set", "host=10.0.0.1", "holding:x")
    assert code == 2 and "address 'holding:x'" in err and "TABLE:ADDRESS" in err
    code, _, err = compd("probe", "modbus", "--set", "host=10.0.0.1", "input:1", "--write", "3")
    assert code == 2 and "cannot be written" in err
    code, _, err = compd("probe", "nobus", "x")
    assert code == 2 and "unknown driver type 'nobus'" in err and "modbus" in err


# -- OPC UA, with security --------------------------------------------------


def test_probe_opcua_shows_each_nodes_variant_type(tmp_path):
    """A secured asyncua server: the settings from a YAML file, each node's variant and value."""
    from tests.drivers.opcua_server import PASSWORD, USERNAME, OpcUaTestServer, make_certificates

    certs = make_certificates(tmp_path)
    (tmp_path / "password.txt").write_text(PASSWORD + "\n")
    server = OpcUaTestServer(certs)
    server.start()
    try:
        settings = tmp_path / "opcua.yaml"
        settings.write_text(yaml.safe_dump({
            "url": server.url,
            "security": {
                "certificate": str(certs.client_cert),
                "private_key": str(certs.client_key),
                "server_certificate": str(certs.server_cert),
            },
            "username": USERNAME,
            "password_file": "password.txt",
        }))  # fmt: skip
        spindle, rpm = server.node_id("T_spindle_degC"), server.node_id("spindle_rpm")
        code, out, err = compd("probe", "opcua", "--settings", settings, spindle, rpm, "--json",
                               "--timeout-s", 10)  # fmt: skip
    finally:
        server.shutdown()
    rows = points(out)
    assert (rows[spindle]["raw"], rows[spindle]["value"]) == ("Double 31.25", 31.25)
    assert (rows[rpm]["raw"], rows[rpm]["value"]) == ("UInt16 12000", 12000.0)
    assert code == 0, err
    assert PASSWORD not in out + err


# -- a serial scanner on a pty ------------------------------------------------


@pytest.fixture
def scanner(tmp_path: Path) -> Iterator[PtyInstrument]:
    instrument = PtyInstrument(tmp_path / "ttyScanner", {"1": 23.456, "2": 351.0})
    yield instrument
    instrument.unplug()


def scanner_config(directory: Path, port: Path) -> Path:
    """T1 and T2 on the scanner (range -50..300 degC), the offset on a Modbus PLC nobody reads."""
    path = machine_config(directory, free_port())
    doc = yaml.safe_load(path.read_text())
    doc["drivers"]["scanner"] = {
        "type": "serial_sensor",
        "settings": {"port": str(port), "channels": ["1", "2"], "range": [-50, 300],
                     "reply_timeout_s": 0.5},
    }  # fmt: skip
    doc["signals"] = {
        f"T{c}_degC": {"driver": "scanner", "address": c, "unit": "degC"} for c in ("1", "2")
    }
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def test_read_a_serial_scanner_shows_each_reply_field(tmp_path, scanner):
    """The reply's field as sent, its value; a value outside the sensor's range shows why it is left out."""
    code, out, _ = compd("read", "--config", scanner_config(tmp_path, scanner.port), "T1_degC",
                         "T2_degC", "--json")  # fmt: skip
    rows = points(out)
    assert (rows["T1_degC"]["raw"], rows["T1_degC"]["value"]) == ("'+23.456'", 23.456)
    assert rows["T2_degC"]["raw"] == "'+351.000'" and rows["T2_degC"]["value"] is None
    assert "outside the sensor's range" in rows["T2_degC"]["problem"]
    assert code == 1


def test_a_busy_serial_port_says_one_master(tmp_path, scanner):
    """The port held by another process (the daemon, say): the error says to stop it first."""
    config = scanner_config(tmp_path, scanner.port)
    with serial.Serial(str(scanner.port), exclusive=True):
        code, out, _ = compd("read", "--config", config, "T1_degC", "--json")
    problem = points(out)["T1_degC"]["problem"]
    assert "cannot connect" in problem and "a serial line has one master" in problem
    assert code == 1


def test_a_busy_modbus_rtu_line_says_one_master(pty_pair):  # noqa: F811  (the fixture)
    """Modbus RTU on a port another process holds: the probe's error names the one-master rule."""
    ours, _, _ = pty_pair
    with serial.Serial(ours, exclusive=True):
        code, out, _ = compd("probe", "modbus", "--set", "transport=rtu", "--set",
                             f"serial_port={ours}", "holding:0", "--json")  # fmt: skip
    problem = points(out)["holding:0"]["problem"]
    assert "cannot connect" in problem and "a serial line has one master" in problem
    assert code == 1


def test_probe_a_profibus_gateway_shows_the_image_bytes(tmp_path):
    """A gateway over Modbus TCP (the simulated one): each value's bytes in the image, a bit with its byte."""
    from tests.drivers.gateway_setup import ThreadedGateway, make_server, modbus_settings

    port = free_port()
    settings = modbus_settings(port)
    gateway = ThreadedGateway(make_server(settings))
    gateway.start()
    try:
        file = tmp_path / "gateway.yaml"
        file.write_text(yaml.safe_dump(settings.model_dump(mode="json")))
        code, out, err = compd("probe", "profibus_gateway", "--settings", file, "in:0:int16",
                               "in:8:int32", "in:14.2", "--json")  # fmt: skip
    finally:
        gateway.close()
    rows = points(out)
    assert (rows["in:0:int16"]["raw"], rows["in:0:int16"]["value"]) == ("FB 2E", -1234.0)
    assert (rows["in:8:int32"]["raw"], rows["in:8:int32"]["value"]) == ("F8 A4 32 EB", -123456789.0)
    assert rows["in:14.2"]["raw"].endswith(" bit 2") and rows["in:14.2"]["value"] == 1.0
    assert code == 0, err


def test_read_loads_the_daemons_stack_only(tmp_path):
    """``compd read`` on a Modbus config imports no toolkit, twin, report, pandas, rich.live or other driver."""
    from tests.test_architecture import NOT_IN_THE_DAEMON, imported_by, loaded

    # A port bound and never listened on: refused, and no other test's server can take it meanwhile.
    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))
        port = held.getsockname()[1]
        status, modules, out = imported_by("read", "--config", machine_config(tmp_path, port))
    assert status == 1 and "cannot connect" in out
    assert "compd.drivers.modbus.driver" in modules
    assert loaded(modules, (*NOT_IN_THE_DAEMON, "asyncua", "can")) == []


def test_probe_loads_no_model_stack():
    """``compd probe`` needs no config: no scipy, no model, no config checks, only its driver."""
    from tests.test_architecture import imported_by, loaded

    argv = ("probe", "modbus", "--set", "host=127.0.0.1", "--set", f"port={free_port()}", "input:0")
    status, modules, out = imported_by(*argv)
    assert status == 1 and "cannot connect" in out
    assert (
        loaded(modules, ("scipy", "compd.model", "compd.service.config.loading", "asyncua")) == []
    )


class _DefectiveDriver:
    """A third-party driver that breaks the contract: ValueError from open, then KeyError from read."""

    def __init__(self) -> None:
        self.opened = 0

    async def open(self) -> None:
        self.opened += 1
        if self.opened == 1:
            raise ValueError("bad checksum table")

    async def read(self, points: list[str]) -> dict[str, float]:
        raise KeyError(points[0])

    async def write(self, values: dict[str, float]) -> None:
        raise RuntimeError("not writable")

    async def close(self) -> None:
        raise RuntimeError("close failed")


def test_a_driver_raising_outside_its_contract_shows_as_a_rows_error_not_a_traceback():
    """read/probe treat any exception of a driver as the loop does: the row says what it raised, the command goes on."""
    from compd.cli.livepoints import LiveDriver, LivePoint, LiveReader

    live = LiveDriver("vendor", _DefectiveDriver(), timeout_s=1.0)
    reader = LiveReader([LivePoint("T1", "signal", "vendor", "ch1")], {"vendor": live})
    first = asyncio.run(reader.read())[0]
    assert "cannot connect: ValueError: bad checksum table" in first.problem
    assert "outside the DriverError contract" in first.problem
    second = asyncio.run(reader.read())[0]
    assert "read failed: KeyError: 'ch1'" in second.problem
    with pytest.raises(Exception, match="write to ch1 failed: RuntimeError: not writable"):
        asyncio.run(live.write("ch1", 1.0))


# -- what a reading leaves open: word order, numbering ------------------------


def test_read_says_a_word_order_the_registers_cannot_tell(tmp_path, plc):
    """An int32 without word= on registers holding 0 reads 0 either way: compd read says so, table and JSON."""
    doc = yaml.safe_load(machine_config(tmp_path, plc).read_text())
    doc["signals"]["T_bed_degC"] = {"driver": "plc", "address": "holding:60:int32", "unit": "um"}
    (tmp_path / "compd.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    code, out, _ = compd("read", "--config", tmp_path / "compd.yaml", "T_bed_degC", "--json")
    row = points(out)["T_bed_degC"]
    assert row["raw"] == "0x0000 0x0000" and row["value"] == 0.0 and code == 0
    assert "0 in either word order" in row["hint"] and "word=little (CDAB)" in row["hint"]
    _, table, _ = compd("read", "--config", tmp_path / "compd.yaml", "T_bed_degC")
    assert "note: 0 in either word order" in " ".join(table.split())


def test_probe_shows_both_word_orders_where_they_differ(plc):
    """Registers 0x0001 0x0002 read 65538 as ABCD and 131073 as CDAB: both shown; word= given, no hint."""
    assert probe(plc, "holding:64:int32:word=big", "--write", 65538, "--yes")[0] == 0
    code, out, _ = probe(plc, "holding:64:int32", "holding:64:int32:word=big",
                         "holding:64:uint16", "--json")  # fmt: skip
    rows = points(out)
    open_order = rows["holding:64:int32"]
    assert open_order["raw"] == "0x0001 0x0002" and open_order["value"] == 65538.0
    assert "65538 as word=big (ABCD)" in open_order["hint"]
    assert "word=little (CDAB) would read 131073" in open_order["hint"]
    assert (
        rows["holding:64:int32:word=big"]["hint"] == "" and rows["holding:64:uint16"]["hint"] == ""
    )
    assert code == 0


def test_probe_hints_at_modicon_numbering_in_a_table(plc):
    """input:30001 and input:40001 are read on the wire as written, each row saying what Modicon would mean."""
    code, out, _ = probe(plc, "input:30001:int16", "input:40001", "30001:int16", "--json")
    rows = points(out)
    assert "input register 1 counted from 1" in rows["input:30001:int16"]["hint"]
    assert "write 30001:int16 or input:0:int16" in rows["input:30001:int16"]["hint"]
    assert "holding register 1, not input register 40001" in rows["input:40001"]["hint"]
    modicon = rows["30001:int16"]
    assert modicon["value"] == -1234.0 and "input:0 on the wire" in modicon["hint"]
    assert code == 1  # input 30001 and 40001 are not on the server: refused, with the hint
