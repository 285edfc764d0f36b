"""Written values overlap nothing across driver entries that reach one device (issue 22, item 2)."""

from __future__ import annotations

import asyncio
import copy
import ipaddress
import os
import re
import socket
import stat
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml

from compd.cli import main
from compd.drivers.endpoints import LOOPBACK, host_key
from compd.drivers.modbus.driver import ModbusDriver
from compd.drivers.modbus.settings import ModbusSettings
from compd.errors import ConfigFileError
from compd.files.yamlplace import resolve_path

from ..drivers.modbus_server import free_port, tcp_server
from .daemon_setup import write_config

SIMULATED_MACHINE = resolve_path("bundled:simulated.yaml", Path("."))


def machine_doc() -> dict[str, Any]:
    """The bundled simulated machine: Modbus TCP on 127.0.0.1:15020, the Z offset int32 at holding:100-101."""
    doc: dict[str, Any] = yaml.safe_load(SIMULATED_MACHINE.read_text())
    doc.pop("simulation")
    doc["model"] = "bundled:simulated_model.yaml"
    return doc


def second_entry(doc: dict[str, Any], **settings: Any) -> dict[str, Any]:
    """``doc`` with a driver entry ``plc2`` like ``plc`` (its settings changed by ``settings``)."""
    doc = copy.deepcopy(doc)
    doc["drivers"]["plc2"] = copy.deepcopy(doc["drivers"]["plc"])
    doc["drivers"]["plc2"]["settings"].update(settings)
    return doc


def issue_doc(**settings: Any) -> dict[str, Any]:
    """The issue's config: the status word at holding:101 through a second entry on the PLC's host:port."""
    doc = second_entry(machine_doc(), **settings)
    doc["status"] = {
        "driver": "plc2",
        "status_address": "holding:101",
        "heartbeat_address": "holding:111",
    }
    return doc


def refusal(tmp_path: Path, doc: dict[str, Any]) -> str:
    with pytest.raises(ConfigFileError) as caught:
        write_config(tmp_path, doc=doc)
    return str(caught.value)


def test_a_status_word_inside_the_offset_through_a_second_entry_is_refused(tmp_path, capsys):
    """check-config refuses a second entry on the PLC's host:port writing inside the int32 offset, naming both."""
    doc = issue_doc()
    path = tmp_path / "compd.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    assert main(["check-config", str(path)]) == 2
    message = capsys.readouterr().err
    assert re.search(
        r"compd\.yaml: line \d+ \(status\.status_address\): address 'holding:101' on driver "
        r"'plc2' overlaps 'holding:100:int32' on driver 'plc', written at line \d+ "
        r"\(outputs\.Z\.address\): both drivers reach modbus loopback:15020",
        message,
    ), message
    assert "unit_ids: separate" in message
    assert "Give every written value its own registers" in message


@pytest.mark.parametrize(
    "host", ["localhost", "LOCALHOST.", "::1", "0.0.0.0"], ids=["name", "case", "ipv6", "any"]
)
def test_every_spelling_of_this_machine_is_one_host(tmp_path, host):
    """The second entry naming the PLC's loopback host another way is the same PLC: refused."""
    assert "both drivers reach modbus loopback:15020" in refusal(tmp_path, issue_doc(host=host))


def test_unit_ids_on_modbus_tcp_reach_one_device_unless_declared_separate(tmp_path):
    """Beside device 1, holding:101:device=0 on Modbus TCP is refused unless both entries say unit_ids: separate."""
    doc = machine_doc()
    doc["status"]["status_address"] = "holding:101:device=0"
    message = refusal(tmp_path, doc)
    assert "'holding:101:device=0' on driver 'plc' overlaps 'holding:100:int32'" in message
    assert "unit ids on one Modbus TCP host:port count as one device" in message
    doc = issue_doc(device_id=0)
    assert "unit_ids: separate" in refusal(tmp_path, doc)
    doc["drivers"]["plc2"]["settings"]["unit_ids"] = "separate"
    assert "overlaps 'holding:100:int32'" in refusal(tmp_path, doc)  # plc still says shared
    doc["drivers"]["plc"]["settings"]["unit_ids"] = "separate"
    assert write_config(tmp_path, doc=doc).doc.status.driver == "plc2"


def test_entries_on_another_port_or_registers_pass(tmp_path):
    """A second entry on another port, or writing registers of its own, is accepted."""
    assert write_config(tmp_path, doc=issue_doc(port=15021)).doc.status.driver == "plc2"
    doc = issue_doc()
    doc["status"]["status_address"] = "holding:102"
    assert write_config(tmp_path, doc=doc).doc.status.status_address == "holding:102"


def test_a_signal_reading_a_written_register_is_refused_and_two_readers_pass(tmp_path):
    """A write overlapping a signal read through another entry is refused; two entries reading one register pass."""
    doc = second_entry(machine_doc())
    doc["signals"]["spindle_power_kw"] |= {"driver": "plc2", "address": "input:4:uint16"}
    assert write_config(tmp_path, doc=doc).doc.signals["spindle_power_kw"].driver == "plc2"
    doc["signals"]["spindle_power_kw"]["address"] = "holding:101"
    message = refusal(tmp_path, doc)
    assert re.search(
        r"\(outputs\.Z\.address\): address 'holding:100:int32' on driver 'plc' overlaps "
        r"'holding:101' on driver 'plc2', read at line \d+ \(signals\.spindle_power_kw\.address\)",
        message,
    ), message


def rtu_doc(tmp_path: Path, status_device: int) -> dict[str, Any]:
    """One RTU entry on a serial line (through a symlink), the status word at holding:101 of ``status_device``."""
    doc = machine_doc()
    line = tmp_path / "ttyUSB0"
    line.touch()
    link = tmp_path / "by-id"
    if not link.exists():
        link.symlink_to(line)
    doc["drivers"]["plc"]["settings"] = {"transport": "rtu", "serial_port": str(link)}
    doc["status"] = {
        "driver": "plc",
        "status_address": f"holding:101:device={status_device}",
        "heartbeat_address": "holding:111",
    }
    return doc


def test_unit_ids_on_a_serial_line_are_addresses_and_zero_is_broadcast(tmp_path):
    """On one RTU line device 2 is another device; device 1 (the offset's) and broadcast 0 are refused."""
    assert write_config(tmp_path, doc=rtu_doc(tmp_path, 2)).doc.status.driver == "plc"
    for device in (1, 0):
        message = refusal(tmp_path, rtu_doc(tmp_path, device))
        assert "overlaps 'holding:100:int32' on driver 'plc', written" in message, message


@pytest.mark.parametrize(
    "second",
    [
        {"type": "modbus", "settings": {"transport": "rtu", "device_id": 2}},
        {"type": "serial_sensor", "settings": {"channels": ["1"]}},
    ],
    ids=["modbus-rtu", "serial-sensor"],
)
def test_a_serial_line_is_one_driver_entrys_alone(tmp_path, second):
    """A second entry on the PLC's RTU line (its device file, not the link) is refused, whatever it reaches there.

    Two masters on one line interleave their requests on the wire and each
    takes the other's replies, so even another device id is no way apart.
    """
    doc = rtu_doc(tmp_path, 2)
    port_key = "serial_port" if second["type"] == "modbus" else "port"
    second["settings"][port_key] = str(tmp_path / "ttyUSB0")
    doc["drivers"]["probe"] = second
    message = refusal(tmp_path, doc)
    assert re.search(
        rf"driver 'probe' opens serial {re.escape(str(tmp_path / 'ttyUSB0'))}, as driver 'plc' "
        r"at line \d+ \(drivers\.plc\) does",
        message,
    ), message
    assert "Reach every device on a serial line through one driver entry" in message
    other = tmp_path / "ttyUSB1"
    other.touch()
    second["settings"][port_key] = str(other)
    assert "probe" in write_config(tmp_path, doc=doc).doc.drivers


@pytest.fixture
def pty_twin(tmp_path: Path) -> Iterator[tuple[str, Path]]:
    """A pseudo-terminal's slave device and a second device node for it (``mknod``, same major/minor)."""
    controller, line = os.openpty()
    try:
        path = os.ttyname(line)
        twin = tmp_path / "ttyTWIN"
        try:
            os.mknod(twin, stat.S_IFCHR | 0o600, os.stat(path).st_rdev)
        except (PermissionError, OSError) as exc:
            pytest.skip(f"cannot make a device node here (mknod: {exc.strerror}): needs CAP_MKNOD")
        yield path, twin
    finally:
        os.close(line)
        os.close(controller)


@pytest.mark.parametrize(
    "second",
    [
        {"type": "modbus", "settings": {"transport": "rtu", "device_id": 2}},
        {"type": "serial_sensor", "settings": {"channels": ["1"]}},
    ],
    ids=["modbus-rtu", "serial-sensor"],
)
def test_a_second_device_node_of_one_serial_line_is_the_same_line(
    tmp_path: Path, pty_twin: tuple[str, Path], second: dict[str, Any]
) -> None:
    """A node made with mknod for the PLC's line (same major/minor, another path) is that line: refused."""
    path, twin = pty_twin
    doc = rtu_doc(tmp_path, 2)
    doc["drivers"]["plc"]["settings"]["serial_port"] = path
    port_key = "serial_port" if second["type"] == "modbus" else "port"
    second["settings"][port_key] = str(twin)
    doc["drivers"]["probe"] = second
    major, minor = os.major(os.stat(path).st_rdev), os.minor(os.stat(path).st_rdev)
    message = refusal(tmp_path, doc)
    assert re.search(
        rf"driver 'probe' opens serial {re.escape(str(twin))} \(device {major}:{minor}\), "
        r"as driver 'plc' at line \d+ \(drivers\.plc\) does",
        message,
    ), message
    other_controller, other_line = os.openpty()  # another pseudo-terminal: another line
    try:
        second["settings"][port_key] = os.ttyname(other_line)
        assert "probe" in write_config(tmp_path, doc=doc).doc.drivers
    finally:
        os.close(other_line)
        os.close(other_controller)


def own_address() -> str:
    """This machine's address on the interface of its default route (a UDP connect sends nothing)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        try:
            probe.connect(("192.0.2.1", 9))  # TEST-NET-1: only routed, never reached
        except OSError as exc:
            pytest.skip(f"no IPv4 route off this machine: {exc}")
        address = str(probe.getsockname()[0])
    if ipaddress.ip_address(address).is_loopback:
        pytest.skip("this machine has no IPv4 address but loopback")
    return address


def test_this_machines_own_address_and_name_are_the_loopback_plc(tmp_path: Path) -> None:
    """127.0.0.1 and the host's own interface address (or its name) on one port are one PLC: refused."""
    address = own_address()
    assert host_key(address) == host_key("127.0.0.1") == LOOPBACK
    assert host_key(socket.gethostname()) == LOOPBACK
    for host in (address, socket.gethostname()):
        assert "both drivers reach modbus loopback:15020" in refusal(tmp_path, issue_doc(host=host))


def gateway_entry(output_register: int = 0, **settings: Any) -> dict[str, Any]:
    """A Profibus gateway over Modbus TCP on the PLC's host:port: 16-byte areas."""
    return {
        "type": "profibus_gateway",
        "settings": {
            "host": "127.0.0.1",
            "port": 15020,
            "input_bytes": 16,
            "output_bytes": 16,
            "output_register": output_register,
            **settings,
        },
    }


def test_two_entries_writing_one_gateway_are_refused_even_apart(tmp_path):
    """A gateway rewrites its whole output area: a second entry writing other bytes of it is refused."""
    doc = machine_doc()
    doc["drivers"] |= {"dp": gateway_entry(), "dp2": gateway_entry()}
    doc["outputs"]["Z"] |= {"driver": "dp", "address": "out:0:int32"}
    doc["status"] = {"driver": "dp2", "status_address": "out:8", "heartbeat_address": "out:10"}
    message = refusal(tmp_path, doc)
    assert re.search(
        r"\(drivers\.dp2\): driver 'dp2' rewrites its whole output area on every write, and so "
        r"does driver 'dp' at line \d+ \(drivers\.dp\): both drivers reach modbus loopback:15020",
        message,
    ), message
    assert "Reach a gateway through one driver entry" in message


def test_a_modbus_entry_writing_inside_a_gateways_output_area_is_refused(tmp_path):
    """holding:205 on the PLC's host:port lies in a gateway's output area at holding 200-207: refused."""
    doc = machine_doc()
    doc["drivers"]["dp"] = gateway_entry(output_register=200)
    doc["status"] = {"driver": "dp", "status_address": "out:8", "heartbeat_address": "out:10"}
    doc["outputs"]["Z"]["address"] = "holding:204:int32"
    message = refusal(tmp_path, doc)
    assert "(drivers.dp): driver 'dp' rewrites its whole output area" in message
    assert "'holding:204:int32' on driver 'plc' is written inside it" in message
    doc["outputs"]["Z"]["address"] = "holding:208:int32"
    assert write_config(tmp_path, doc=doc).doc.outputs["Z"].address == "holding:208:int32"


def can_gateway(node_id: int) -> dict[str, Any]:
    """A CANopen gateway on the virtual bus ``vcan-overlap``: 16 bytes in, 8 out."""
    return {
        "type": "profibus_gateway",
        "settings": {
            "transport": "can",
            "interface": "virtual",
            "channel": "vcan-overlap",
            "node_id": node_id,
            "input_bytes": 16,
            "output_bytes": 8,
        },
    }


def test_can_gateway_entries_of_one_node_are_refused_and_other_nodes_pass(tmp_path):
    """Two entries writing node 5's RPDOs on one CAN bus are refused; node 6 on that bus is another image."""
    doc = machine_doc()
    doc["drivers"] |= {"dp": can_gateway(5), "dp2": can_gateway(5)}
    doc["outputs"]["Z"] |= {"driver": "dp", "address": "out:0:int32"}
    doc["status"] = {"driver": "dp2", "status_address": "out:4", "heartbeat_address": "out:6"}
    assert "both drivers reach can virtual:vcan-overlap" in refusal(tmp_path, doc)
    doc["drivers"]["dp2"] = can_gateway(6)
    assert write_config(tmp_path, doc=doc).doc.status.driver == "dp2"


def opcua_entry(host: str) -> dict[str, Any]:
    return {"type": "opcua", "settings": {"url": f"opc.tcp://{host}:4840/", "security": "none"}}


def opcua_doc(status: str, heartbeat: str, *, reader: str = "ns=2;s=Machine.T") -> dict[str, Any]:
    """The Z offset on Modbus; status and heartbeat through ``ua``; a signal read through ``ua2``, same server."""
    doc = machine_doc()
    doc["drivers"] |= {"ua": opcua_entry("127.0.0.1"), "ua2": opcua_entry("localhost")}
    doc["status"] = {"driver": "ua", "status_address": status, "heartbeat_address": heartbeat}
    doc["signals"]["spindle_power_kw"] |= {"driver": "ua2", "address": reader}
    return doc


def test_an_opc_ua_node_written_through_one_entry_and_read_through_another_is_refused(tmp_path):
    """Two entries on one OPC UA server (127.0.0.1, localhost): a node written by one, read by the other: refused."""
    doc = opcua_doc("ns=2;s=Machine.T", "ns=2;s=Machine.hb")
    message = refusal(tmp_path, doc)
    assert "'ns=2;s=Machine.T' on driver 'ua2', read at line" in message
    assert "both drivers reach opc.tcp loopback:4840" in message
    doc["status"]["status_address"] = "ns=2;s=Machine.status"
    assert write_config(tmp_path, doc=doc).doc.status.driver == "ua"


def test_a_nodeid_and_a_browse_path_on_a_written_server_are_refused(tmp_path):
    """Only the server can tell a NodeId and a browse path apart: mixed where compd writes, refused with the fix."""
    doc = opcua_doc("ns=2;s=Machine.status", "0:Objects/2:Machine/2:hb")
    message = refusal(tmp_path, doc)
    assert re.search(
        r"\(status\.heartbeat_address\): address '0:Objects/2:Machine/2:hb' on driver 'ua' names "
        r"its node as a browse path, 'ns=2;s=Machine\.T' at line \d+ "
        r"\(signals\.spindle_power_kw\.address\) as a NodeId",
        message,
    ), message
    assert "Name every node on this server as a NodeId" in message
    doc = opcua_doc("0:Objects/2:Machine/2:status", "0:Objects/2:Machine/2:hb")
    doc["signals"]["spindle_power_kw"]["address"] = "0:Objects/2:Machine/2:T"
    assert write_config(tmp_path, doc=doc).doc.status.driver == "ua"


def test_nodeids_and_browse_paths_mix_where_compd_only_reads(tmp_path):
    """A server compd only reads may be named both ways."""
    doc = machine_doc()
    doc["drivers"]["ua"] = opcua_entry("127.0.0.1")
    doc["signals"]["spindle_power_kw"] |= {"driver": "ua", "address": "ns=2;s=Machine.P"}
    doc["signals"]["spindle_speed_rpm"] |= {"driver": "ua", "address": "0:Objects/2:M/2:rpm"}
    assert write_config(tmp_path, doc=doc).doc.signals["spindle_speed_rpm"].driver == "ua"


def test_host_keys():
    """Loopback in any spelling is one host; IP addresses compare canonically; other names in lower case."""
    assert {host_key(h) for h in ("localhost", "127.0.0.1", "127.0.1.1", "::1", "[::1]")} == {
        LOOPBACK
    }
    assert host_key("::ffff:10.0.0.5") == host_key("10.0.0.5") == "10.0.0.5"
    assert host_key("fe80:0::1%eth0") == "fe80::1"
    assert host_key("PLC-Nowhere.invalid.") == "plc-nowhere.invalid"


def test_compd_run_refuses_the_issue_config_before_writing_to_the_plc(tmp_path, capsys):
    """compd run on the issue's config stops at the overlap: a real Modbus PLC's offset registers are never written."""
    port = free_port()
    server = tcp_server(port)
    server.start()
    try:
        doc = issue_doc(port=port)
        doc["drivers"]["plc"]["settings"]["port"] = port
        doc["state"] = {"directory": str(tmp_path / "state")}
        doc["control_socket"] = str(tmp_path / "c.sock")
        path = tmp_path / "compd.yaml"
        path.write_text(yaml.safe_dump(doc, sort_keys=False))
        code = main(["run", "--config", str(path), "--duration-s", "3", "--live-every", "1000"])
        assert code == 2, capsys.readouterr().err
        assert "overlaps 'holding:100:int32'" in capsys.readouterr().err
        plc = ModbusDriver(
            ModbusSettings(host="127.0.0.1", port=port), now=time.monotonic, base_dir=Path()
        )

        async def offset_registers() -> dict[str, float]:
            await plc.open()
            try:
                return await plc.read(["holding:100:int32", "holding:101"])
            finally:
                await plc.close()

        assert asyncio.run(offset_registers()) == {"holding:100:int32": 0.0, "holding:101": 0.0}
    finally:
        server.stop()
