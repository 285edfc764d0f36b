"""The simulated PLC's OPC UA server, secured, against compd's own OPC UA driver in one event loop.

One server per module (building it takes about two seconds): Basic256Sha256
with SignAndEncrypt, certificates generated into a fresh directory on its
first start, one user whose password comes from a file. The tests run their
coroutines on the module's event loop, where the server lives, exactly as
the simulated machine runs server and service together.
"""

from __future__ import annotations

import asyncio
import socket
import time
from collections.abc import Coroutine, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import pytest

from compd.drivers.opcua.driver import OpcUaDriver, OpcUaSettings
from compd.errors import DriverProtocolError
from compd.service.loop.clock import VirtualClock
from compd.service.loop.links import DriverLink
from compd.sim.plc.opcua import OpcUaPlcServer, parse_address
from compd.sim.plc.opcua_security import ensure_client_certificate, ensure_server_certificate
from tests.ports import free_port
from tests.reconnect import seconds_until_read

T = TypeVar("T")

USERNAME = "operator"
PASSWORD = "s3cret plc password"
T_STRING = "ns=2;s=Machine.T_spindle_degC"
T_NUMERIC = "ns=3;i=1001"
T_PATH = "0:Objects/2:Machine/2:T_bed_degC"
COMP_X = "ns=2;s=Machine.comp_x_um"
COMP_Z = "0:Objects/2:Machine/2:Axes/2:comp_z_um"
HEARTBEAT = "ns=2;i=500"
INPUTS = [T_STRING, T_NUMERIC, T_PATH]
OUTPUTS = [COMP_X, COMP_Z, HEARTBEAT]
SECURITY = {  # relative to the tmp dir; none of these files exists before the first start
    "certificate": "pki/client.der",
    "private_key": "pki/client.key.pem",
    "server_certificate": "pki/plc.der",
}


def settings(port: int, **overrides: Any) -> OpcUaSettings:
    """The driver settings both sides use: relative file names, resolved against the tmp dir."""
    values: dict[str, Any] = {
        "url": f"opc.tcp://127.0.0.1:{port}/compd/",
        "security": SECURITY,
        "username": USERNAME,
        "password_file": "password.txt",
        "request_timeout_s": 1.0,
    }
    values.update(overrides)
    return OpcUaSettings.model_validate(values)


@dataclass
class Plc:
    loop: asyncio.AbstractEventLoop
    server: OpcUaPlcServer
    port: int
    base_dir: Path
    writes: list[tuple[str, float]] = field(default_factory=list)

    def run(self, coro: Coroutine[Any, Any, T]) -> T:
        return self.loop.run_until_complete(coro)

    def driver(self, **overrides: Any) -> OpcUaDriver:
        return OpcUaDriver(
            settings(self.port, **overrides), now=time.monotonic, base_dir=self.base_dir
        )


@pytest.fixture(scope="module")
def plc(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Plc]:
    base_dir = tmp_path_factory.mktemp("opcua_plc")
    (base_dir / "password.txt").write_text(PASSWORD + "\n")
    loop = asyncio.new_event_loop()
    writes: list[tuple[str, float]] = []
    port = free_port()
    server = OpcUaPlcServer(
        settings(port),
        inputs=INPUTS,
        outputs=OUTPUTS,
        on_write=lambda address, raw: writes.append((address, raw)),
        base_dir=base_dir,
    )
    server.publish({T_STRING: 31.25})  # before the first start: served from it on
    plc = Plc(loop, server, port, base_dir, writes)
    plc.run(server.start())
    yield plc
    plc.run(server.stop())
    loop.close()


def test_first_start_generates_the_certificates(plc: Plc) -> None:
    """Missing server and client certificates are generated where the settings name them, keys beside."""
    pki = plc.base_dir / "pki"
    assert sorted(p.name for p in pki.iterdir()) == [
        "client.der",
        "client.key.pem",
        "plc.der",
        "plc.key.pem",
    ]
    assert (pki / "plc.der").read_bytes()[:1] == b"\x30"  # DER, as the suffix says
    assert (pki / "plc.key.pem").read_bytes().startswith(b"-----BEGIN PRIVATE KEY")
    assert (pki / "client.key.pem").stat().st_mode & 0o077 == 0


def test_published_values_read_back(plc: Plc) -> None:
    """Values published by string NodeId, numeric NodeId and browse path are what the driver reads."""
    driver = plc.driver()

    async def scenario() -> tuple[dict[str, float], dict[str, float]]:
        await driver.open()
        first = await driver.read(INPUTS)
        plc.server.publish({T_STRING: 40.5, T_NUMERIC: -3.0, T_PATH: 22.125})
        second = await driver.read(INPUTS)
        await driver.close()
        return first, second

    first, second = plc.run(scenario())
    assert first == {T_STRING: 31.25, T_NUMERIC: 0.0, T_PATH: 0.0}
    assert second == {T_STRING: 40.5, T_NUMERIC: -3.0, T_PATH: 22.125}


def test_subscribers_see_published_values(plc: Plc) -> None:
    """A data-change subscription on an input is notified of each published value, as on a real PLC."""
    server = plc.server._server  # the asyncua server: its own session subscribes
    assert server is not None
    seen: asyncio.Queue[float] = asyncio.Queue()

    class Handler:
        def datachange_notification(self, node: Any, value: float, data: Any) -> None:
            seen.put_nowait(value)

    async def scenario() -> list[float]:
        subscription = await server.create_subscription(10, Handler())
        await subscription.subscribe_data_change(server.get_node(T_NUMERIC))
        first = await asyncio.wait_for(seen.get(), 60.0)  # hang guards
        plc.server.publish({T_NUMERIC: 8.5})
        second = await asyncio.wait_for(seen.get(), 60.0)
        await subscription.delete()
        return [first, second]

    plc.server.publish({T_NUMERIC: 1.5})
    assert plc.run(scenario()) == [1.5, 8.5]


def test_client_writes_reach_on_write_once(plc: Plc) -> None:
    """Each value the driver writes is reported once as (address, raw), and reads back."""
    driver = plc.driver()
    plc.writes.clear()

    async def scenario() -> dict[str, float]:
        await driver.open()
        await driver.write({COMP_X: 12.5, COMP_Z: -4.0, HEARTBEAT: 1.0})
        await driver.write({HEARTBEAT: 2.0})
        back = await driver.read(OUTPUTS)
        await driver.close()
        return back

    assert plc.run(scenario()) == {COMP_X: 12.5, COMP_Z: -4.0, HEARTBEAT: 2.0}
    assert plc.writes == [(COMP_X, 12.5), (COMP_Z, -4.0), (HEARTBEAT, 1.0), (HEARTBEAT, 2.0)]


def test_inputs_are_read_only(plc: Plc) -> None:
    """A client cannot write an input: refused, and nothing is reported."""
    driver = plc.driver()
    plc.writes.clear()

    async def scenario() -> None:
        await driver.open()
        try:
            await driver.write({T_STRING: 99.0})
        finally:
            await driver.close()

    with pytest.raises(DriverProtocolError, match="refused writes"):
        plc.run(scenario())
    assert plc.writes == []


def test_wrong_password_is_refused(plc: Plc, monkeypatch: pytest.MonkeyPatch) -> None:
    """Only the configured user with its password logs in."""
    monkeypatch.setenv("COMPD_TEST_PLC_PASSWORD", "not the password")
    driver = plc.driver(password_file=None, password_env="COMPD_TEST_PLC_PASSWORD")
    with pytest.raises(DriverProtocolError, match="wrong username or password"):
        plc.run(driver.open())


def test_another_client_certificate_is_refused(plc: Plc) -> None:
    """Only the client certificate named in the settings is trusted."""
    rogue = plc.base_dir / "rogue"  # valid, same URI, but not the certificate the server trusts
    ensure_client_certificate(rogue / "client.der", rogue / "client.key.pem", None)
    driver = plc.driver(
        security={
            **SECURITY,
            "certificate": "rogue/client.der",
            "private_key": "rogue/client.key.pem",
        }
    )
    with pytest.raises(DriverProtocolError, match="does not trust the client certificate"):
        plc.run(driver.open())


def test_restart_drops_clients_and_the_link_reconnects(plc: Plc) -> None:
    """stop() drops the connection; start() again is fast, values survive, DriverLink reconnects."""
    clock = VirtualClock()  # the backoff's clock: the retries counted, not the machine's speed
    # The timeouts only end a hung attempt: a secure session takes seconds on a busy host.
    link = DriverLink(
        "plc", plc.driver(request_timeout_s=2.0), clock, timeout_s=10.0, backoff_min_s=0.05
    )

    async def scenario() -> tuple[dict[str, float], dict[str, float], float]:
        await link.open()
        plc.server.publish({T_STRING: 55.0})
        assert await link.read([T_STRING]) == {T_STRING: 55.0}
        await plc.server.stop()
        down = await link.read([T_STRING])
        await plc.server.start()
        await seconds_until_read(link, clock, [T_STRING])
        values = await link.read([T_STRING])
        await link.close()
        return down, values, plc.server.last_start_s

    down, values, restart_s = plc.run(scenario())
    assert down == {} and values == {T_STRING: 55.0}
    assert link.reconnects == 1 and restart_s < 0.5


def test_existing_certificates_are_reused_not_regenerated(plc: Plc) -> None:
    """A server built again with the same settings loads the files of the first start, unchanged.

    (Building a second server costs seconds; the restart test shows the
    driver, which trusts pki/plc.der, connecting to the same server again.)
    """
    pki = plc.base_dir / "pki"
    before = {p.name: p.read_bytes() for p in pki.iterdir()}
    der, key_pem, uri = ensure_server_certificate(pki / "plc.der", "urn:other", "127.0.0.1")
    trusted = ensure_client_certificate(pki / "client.der", pki / "client.key.pem", None)
    assert {p.name: p.read_bytes() for p in pki.iterdir()} == before
    assert der == before["plc.der"] and key_pem == before["plc.key.pem"]
    assert uri == "urn:compd:sim:plc"  # from the certificate, not the default passed in
    assert trusted == before["client.der"]


def test_publish_refuses_unknown_addresses(plc: Plc) -> None:
    """Publishing an address the server was not built with is the machine's bug: KeyError naming it."""
    with pytest.raises(KeyError, match="ns=2;s=Nowhere"):
        plc.server.publish({"ns=2;s=Nowhere": 1.0})


@pytest.mark.parametrize(
    ("address", "message"),
    [
        ("i=2258", "namespace 0"),
        ("ns=2;x=oops", "neither a NodeId"),
        ("0:Objects/2:Machine<0:HasProperty>2:T", "'/' and '.'"),
    ],
)
def test_bad_addresses_are_refused_with_the_fix(address: str, message: str) -> None:
    """An address the simulated PLC cannot serve is a ValueError saying what to write instead."""
    with pytest.raises(ValueError, match=message):
        parse_address(address)


def test_a_taken_port_is_a_clear_error_before_building(tmp_path: Path) -> None:
    """start() on a port another program listens on raises OSError naming the url and the fix."""
    with socket.socket() as other:
        other.bind(("127.0.0.1", 0))
        other.listen()
        server = OpcUaPlcServer(
            settings(other.getsockname()[1]),
            inputs=[T_STRING],
            outputs=[],
            on_write=lambda a, v: None,
            base_dir=tmp_path,
        )
        with pytest.raises(
            OSError, match=r"cannot listen at opc\.tcp://127\.0\.0\.1:.*Change the port"
        ):
            asyncio.run(server.start())
    assert not (tmp_path / "pki").exists()  # nothing generated for a server that never ran
