"""The OPC UA driver against a real, secured asyncua server started by the tests.

One server per test session (Basic256Sha256/SignAndEncrypt, username
tokens only, one trusted client certificate); the contract suite reaches it
through a TCP proxy that each test can cut. The restart test has its own
server, stopped and started again on the same port.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import structlog
import yaml
from asyncua import ua
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from compd.drivers.opcua.driver import OpcUaDriver, OpcUaSettings
from compd.drivers.opcua.values import NUMERIC_TYPES
from compd.drivers.registry import driver_names, load_driver_type
from compd.errors import (
    ConfigFileError,
    DriverDisconnectedError,
    DriverError,
    DriverProtocolError,
    DriverTimeoutError,
)
from compd.service.config.loading import parse_config
from compd.service.loop.clock import RealClock, VirtualClock
from compd.service.loop.links import DriverLink
from tests.reconnect import seconds_until_read

from .contract import ContractSetup, DriverContract
from .opcua_server import (
    PASSWORD,
    SINUMERIK_DBD,
    USERNAME,
    Certificates,
    OpcUaTestServer,
    make_certificates,
)


@pytest.fixture(scope="session")
def certs(tmp_path_factory: pytest.TempPathFactory) -> Certificates:
    directory = tmp_path_factory.mktemp("opcua_pki")
    certs = make_certificates(directory)
    (directory / "password.txt").write_text(PASSWORD + "\n")
    return certs


@pytest.fixture(scope="session")
def server(certs: Certificates) -> Iterator[OpcUaTestServer]:
    server = OpcUaTestServer(certs)
    server.start()
    yield server
    server.shutdown()


def make_driver(
    certs: Certificates, url: str, *, security: dict[str, str] | None = None, **settings: object
) -> OpcUaDriver:
    """A driver with the trusted client certificate and the password from a file, unless overridden."""
    sec = {
        "certificate": str(certs.client_cert),
        "private_key": str(certs.client_key),
        "server_certificate": str(certs.server_cert),
    }
    sec.update(security or {})
    values: dict[str, object] = {
        "url": url,
        "security": sec,
        "username": USERNAME,
        "password_file": "password.txt",
        "request_timeout_s": 1.0,
    }
    values.update(settings)
    return OpcUaDriver(
        OpcUaSettings.model_validate(values), now=time.monotonic, base_dir=certs.server_cert.parent
    )


async def opened(driver: OpcUaDriver) -> OpcUaDriver:
    await driver.open()
    return driver


def refused(driver: OpcUaDriver) -> DriverError:
    """The error open() raises (the test fails if it connects)."""

    async def scenario() -> None:
        try:
            await driver.open()
        finally:
            await driver.close()

    with pytest.raises(DriverError) as info:
        asyncio.run(scenario())
    return info.value


def test_registered_with_its_settings():
    """The opcua driver is in the registry under 'opcua' and owns its settings model."""
    assert load_driver_type("opcua") is OpcUaDriver and "opcua" in driver_names()
    assert OpcUaDriver.settings_model is OpcUaSettings


def test_settings_are_validated():
    """Two password sources, a password without a user, and credentials in the URL are config errors."""
    url = "opc.tcp://plc:4840"
    for bad in (
        {"url": url, "username": "u", "password_file": "f", "password_env": "E"},
        {"url": url, "password_env": "E"},
        {"url": "opc.tcp://u:secret@plc:4840"},
        {"url": "http://plc:4840"},
        {"url": url, "timeout": 1},
    ):
        with pytest.raises(ValidationError):
            OpcUaSettings.model_validate(bad)


def test_security_is_required_and_none_must_be_written_out():
    """No security block is an error naming the fix; 'security: none' is accepted without a password."""
    with pytest.raises(ValidationError, match=r"'security' is missing: give security\.certificate"):
        OpcUaSettings.model_validate({"url": "opc.tcp://plc:4840"})
    with pytest.raises(ValidationError, match="write 'security: none'"):
        OpcUaSettings.model_validate({"url": "opc.tcp://plc:4840", "security": None})
    settings = OpcUaSettings.model_validate({"url": "opc.tcp://plc:4840", "security": "none"})
    assert settings.security is None


def test_security_defaults_to_sign_and_encrypt():
    """A security block naming only the certificates means Basic256Sha256 with SignAndEncrypt."""
    block = {"certificate": "c.pem", "private_key": "k.pem", "server_certificate": "s.der"}
    settings = OpcUaSettings.model_validate({"url": "opc.tcp://plc:4840", "security": block})
    assert settings.security is not None
    assert (settings.security.policy, settings.security.mode) == (
        "Basic256Sha256",
        "SignAndEncrypt",
    )


CONFIG_WITH_OPCUA = """\
schema: compd.config/1
model: model.yaml
drivers:
  cnc:
    type: opcua
    settings:
      url: opc.tcp://127.0.0.1:4840/
{security}      username: compd
      password_env: COMPD_OPCUA_PASSWORD
signals:
  T_spindle_degC: {{driver: cnc, address: "ns=2;s=Machine.T_spindle", unit: degC}}
outputs:
  Z: {{model_output: disp_z_um, driver: cnc, address: "ns=2;s=Machine.comp_z",
       max_offset_um: 50, max_rate_um_per_s: 1}}
"""


@pytest.mark.parametrize("security", ["", "      security: none\n"], ids=["absent", "none"])
def test_a_password_without_security_is_refused_by_check_config(tmp_path, security):
    """A username and password without security (absent or none) is refused: file, place and fix named."""
    path = tmp_path / "compd.yaml"
    with pytest.raises(ConfigFileError) as info:
        parse_config(CONFIG_WITH_OPCUA.format(security=security), path)
    message = str(info.value)
    assert message.startswith(f"{path}: line ") and "(drivers.cnc.settings)" in message
    assert "security" in message and "security.server_certificate" in message


def test_default_security_connects_with_sign_and_encrypt(certs, server):
    """Certificates alone (no policy, no mode) connect to a server offering only Basic256Sha256/SignAndEncrypt."""

    async def scenario() -> tuple[str, str]:
        driver = await opened(make_driver(certs, server.url))
        try:
            client = driver._client
            assert client is not None
            policy = client.security_policy
            await driver.read([server.node_id("spindle_rpm")])
            return policy.URI, policy.Mode.name
        finally:
            await driver.close()

    uri, mode = asyncio.run(scenario())
    assert uri.endswith("#Basic256Sha256") and mode == "SignAndEncrypt"


def test_a_policy_the_server_lacks_is_named(certs, server):
    """Asking for Aes256_Sha256_RsaPss of a server without it is refused, naming what the server offers."""
    error = refused(make_driver(certs, server.url, security={"policy": "Aes256_Sha256_RsaPss"}))
    assert isinstance(error, DriverProtocolError)
    assert "does not offer Aes256_Sha256_RsaPss/SignAndEncrypt" in str(error)
    assert "Basic256Sha256/SignAndEncrypt" in str(error)


def test_the_commented_example_config_is_valid():
    """The commented-out OPC UA driver in config/compd.example.yaml validates once uncommented."""
    text = (Path(__file__).parents[2] / "config" / "compd.example.yaml").read_text()
    block = text[text.index("  # cnc:") : text.index("  # OPC UA addresses")]
    doc = yaml.safe_load("\n".join(line.replace("  # ", "  ", 1) for line in block.splitlines()))
    assert doc["cnc"]["type"] == "opcua"
    settings = OpcUaSettings.model_validate(doc["cnc"]["settings"])
    assert settings.security is not None and settings.security.mode == "SignAndEncrypt"


def test_reads_every_numeric_type_by_node_id_and_browse_path(certs, server):
    """Double, Float, UInt16, Int32 and Boolean nodes read as floats, by NodeId or by browse path."""
    ns = server.namespace_index
    path = f"0:Objects/{ns}:Machine/{ns}:T_spindle_degC"
    ids = {n: server.node_id(n) for n in ("T_bed_degC", "spindle_rpm", "power_w", "running")}

    async def scenario() -> dict[str, float]:
        driver = await opened(make_driver(certs, server.url))
        try:
            return await driver.read([path, *ids.values()])
        finally:
            await driver.close()

    values = asyncio.run(scenario())
    assert values == {
        path: 31.25,
        ids["T_bed_degC"]: 22.5,
        ids["spindle_rpm"]: 12000.0,
        ids["power_w"]: -1500.0,
        ids["running"]: 1.0,
    }


def test_one_read_request_per_tick(certs, server):
    """After the first read resolves the nodes, each read is a single OPC UA Read of all nodes."""
    points = [server.node_id(n) for n in ("T_spindle_degC", "T_bed_degC", "spindle_rpm")]
    calls = []

    async def scenario() -> None:
        driver = await opened(make_driver(certs, server.url))
        await driver.read(points)
        client = driver._client
        assert client is not None
        original = client.uaclient.read_attributes

        async def counting(nodes, attr):  # counts the real call, changes nothing
            calls.append(len(nodes))
            return await original(nodes, attr)

        client.uaclient.read_attributes = counting  # type: ignore[method-assign]
        for _ in range(5):
            await driver.read(points)
        await driver.close()

    asyncio.run(scenario())
    assert calls == [3] * 5


def test_bad_quality_is_no_value(certs, server):
    """A node whose status is Bad is left out of the result; the good nodes of the batch still read."""
    faulty, good = server.node_id("T_faulty_degC"), server.node_id("T_spindle_degC")

    async def scenario() -> dict[str, float]:
        driver = await opened(make_driver(certs, server.url))
        try:
            return await driver.read([faulty, good])
        finally:
            await driver.close()

    assert asyncio.run(scenario()) == {good: 31.25}


def test_writes_use_the_node_type(certs, server):
    """Writes reach the server with each node's own type: Int16/Int32 rounded, Double, UInt16, Boolean."""
    names = ("comp_x_um", "comp_y_0p1um", "comp_z_0p1um", "status_word", "heartbeat")
    values = dict(zip(names, (-12.75, -123.0, 70000.4, 5.0, 1.0), strict=True))

    async def scenario() -> None:
        driver = await opened(make_driver(certs, server.url))
        try:
            await driver.write({server.node_id(n): v for n, v in values.items()})
        finally:
            await driver.close()

    asyncio.run(scenario())
    held = {n: server.value(n) for n in names}
    assert held == {
        "comp_x_um": -12.75,
        "comp_y_0p1um": -123,
        "comp_z_0p1um": 70000,
        "status_word": 5,
        "heartbeat": True,
    }
    assert isinstance(held["comp_y_0p1um"], int) and isinstance(held["heartbeat"], bool)


def test_a_string_node_id_with_slashes_is_a_node_id_not_a_browse_path(certs, server):
    """ns=N;s=/Plc/DB9000.DBD10:DINT (SINUMERIK's form) writes and reads back that node."""
    address = f"ns={server.namespace_index};s={SINUMERIK_DBD}"
    settings = OpcUaSettings.model_validate({"url": server.url, "security": "none"})
    assert OpcUaDriver.naming(address, settings) == "a NodeId"
    assert {cell[-1] for cell in OpcUaDriver.footprint(address, settings)} == {address}

    async def scenario() -> dict[str, float]:
        driver = await opened(make_driver(certs, server.url))
        try:
            await driver.write({address: -123.0})
            return await driver.read([address])
        finally:
            await driver.close()

    assert asyncio.run(scenario()) == {address: -123.0}
    assert server.value("sinumerik_dbd") == -123


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("comp_y_0p1um", 32767.6),  # rounds to 32768: one past Int16
        ("comp_y_0p1um", -40000.0),
        ("status_word", -1.0),  # UInt16
        ("comp_z_0p1um", float("nan")),
        ("heartbeat", 0.5),
    ],
)
def test_out_of_range_writes_send_nothing(certs, server, name, value):
    """A value that does not fit the node's type is a DriverProtocolError and no value of the batch is sent."""
    server.set_value("comp_x_um", 0.0)
    before = server.value(name)

    async def scenario() -> None:
        driver = await opened(make_driver(certs, server.url))
        try:
            await driver.write({server.node_id("comp_x_um"): 7.0, server.node_id(name): value})
        finally:
            await driver.close()

    with pytest.raises(DriverProtocolError, match=r"does not fit|not 0 or 1|not finite"):
        asyncio.run(scenario())
    assert server.value(name) == before and server.value("comp_x_um") == 0.0


def test_rejected_write_names_the_node_and_status(certs, server):
    """A write the server refuses (read-only node) raises DriverProtocolError with the node and status."""
    node = server.node_id("T_spindle_degC")

    async def scenario() -> None:
        driver = await opened(make_driver(certs, server.url))
        try:
            await driver.write({node: 1.0})
        finally:
            await driver.close()

    with pytest.raises(DriverProtocolError, match=r"refused writes .*T_spindle_degC: Bad"):
        asyncio.run(scenario())
    assert server.value("T_spindle_degC") == 31.25


@pytest.mark.parametrize(
    ("address", "message"),
    [
        ("label", "not a number"),
        ("ns=2;s=Machine.nope", "no variable"),
        ("0:Objects/2:Nope", "no node at browse path"),
        ("ns=x;q=", "neither a NodeId"),
    ],
)
def test_unusable_addresses_are_protocol_errors(certs, server, address, message):
    """Strings, unknown NodeIds, unknown browse paths and unparsable addresses raise DriverProtocolError."""
    if address == "label":
        address = server.node_id("label")

    async def scenario() -> None:
        driver = await opened(make_driver(certs, server.url))
        try:
            await driver.read([address])
        finally:
            await driver.close()

    with pytest.raises(DriverProtocolError, match=message):
        asyncio.run(scenario())


def test_password_from_environment(certs, server, monkeypatch):
    """password_env supplies the password; a good user connects and reads."""
    monkeypatch.setenv("COMPD_TEST_OPCUA_PW", PASSWORD)

    async def scenario() -> dict[str, float]:
        driver = make_driver(
            certs, server.url, password_file=None, password_env="COMPD_TEST_OPCUA_PW"
        )
        await driver.open()
        try:
            return await driver.read([server.node_id("spindle_rpm")])
        finally:
            await driver.close()

    assert asyncio.run(scenario()) == {server.node_id("spindle_rpm"): 12000.0}


def test_wrong_password_is_refused_and_never_shown(certs, server, monkeypatch, caplog):
    """A wrong password is refused with a message saying so, and the password appears in no log or error."""
    wrong = "wrong-password-1234"
    monkeypatch.setenv("COMPD_TEST_OPCUA_PW", wrong)
    driver = make_driver(certs, server.url, password_file=None, password_env="COMPD_TEST_OPCUA_PW")
    with caplog.at_level(logging.DEBUG), structlog.testing.capture_logs() as events:
        error = refused(driver)
    assert isinstance(error, DriverProtocolError)
    assert "wrong username or password" in str(error)
    text = f"{error!r} {error.__cause__!r} {caplog.text} {events!r}"
    assert wrong not in text and PASSWORD not in text


def test_missing_password_variable_is_named(certs, server, monkeypatch):
    """An unset password_env is a DriverError naming the variable."""
    monkeypatch.delenv("COMPD_TEST_OPCUA_UNSET", raising=False)
    driver = make_driver(
        certs, server.url, password_file=None, password_env="COMPD_TEST_OPCUA_UNSET"
    )
    assert "COMPD_TEST_OPCUA_UNSET" in str(refused(driver))


def test_untrusted_client_certificate_is_refused(certs, server):
    """A client certificate the server does not trust is refused with a message that says so."""
    driver = make_driver(
        certs,
        server.url,
        security={"certificate": str(certs.rogue_cert), "private_key": str(certs.rogue_key)},
    )
    error = refused(driver)
    assert isinstance(error, DriverProtocolError)
    assert "does not trust the client certificate" in str(error)


def trusting_another_server(certs: Certificates, url: str, request_timeout_s: float) -> OpcUaDriver:
    """A driver whose security.server_certificate is not the server's (the client's own)."""
    return make_driver(
        certs,
        url,
        security={"server_certificate": str(certs.client_cert)},
        request_timeout_s=request_timeout_s,
    )


def test_untrusted_server_certificate_is_refused(certs, server):
    """A server whose certificate is not security.server_certificate is refused as not trusted."""
    error = refused(trusting_another_server(certs, server.url, 0.3))
    assert isinstance(error, DriverProtocolError)
    assert "not security.server_certificate" in str(error) and "not trusted" in str(error)


def test_untrusted_server_certificate_says_not_trusted_through_the_link(certs, server):
    """Through a link with the example's timeouts (0.5 s, 0.4 s) the logged error says "not trusted"."""
    driver = trusting_another_server(certs, server.url, 0.4)
    link = DriverLink("cnc", driver, RealClock(), timeout_s=0.5)

    async def scenario() -> None:
        await link.open()
        await link.close()

    with structlog.testing.capture_logs() as events:
        asyncio.run(scenario())
    errors = [e for e in events if e["log_level"] == "error"]
    assert not link.up and len(errors) == 1
    assert "not trusted" in errors[0]["error"] and "timed out" not in errors[0]["error"]


def test_garbage_replies_are_driver_errors(certs, server):
    """A peer answering bytes that are not OPC UA gives a bounded DriverError, not a library exception."""
    url = f"opc.tcp://127.0.0.1:{server.garbage_port()}/compd/"
    started = time.monotonic()
    error = refused(make_driver(certs, url, request_timeout_s=0.5))
    # asyncua drops the socket on an unparsable reply but leaves the request
    # pending: it ends as a timeout (then the endpoint probe fails the same way).
    assert isinstance(error, DriverTimeoutError | DriverDisconnectedError | DriverProtocolError)
    assert time.monotonic() - started < 3.0


class TestOpcUaContract(DriverContract):
    """The OPC UA driver passes the driver contract against the secured server, through a cuttable proxy."""

    @pytest.fixture
    def setup(self, certs: Certificates, server: OpcUaTestServer) -> ContractSetup:
        proxy = server.proxy()
        return ContractSetup(
            driver=make_driver(certs, proxy.url),
            readable=(server.node_id("T_spindle_degC"), server.node_id("spindle_rpm")),
            writable=server.node_id("comp_x_um"),
            missing=server.node_id("no_such_node"),
            break_connection=proxy.cut,
        )


@pytest.fixture(scope="module")
def restart_server(certs: Certificates) -> Iterator[OpcUaTestServer]:
    server = OpcUaTestServer(certs)
    server.start()
    yield server
    server.shutdown()


def test_server_stopped_and_restarted(certs, restart_server: OpcUaTestServer):
    """Server gone: reads raise DriverDisconnectedError and the link never raises; back: reconnected within 5 s."""
    point = restart_server.node_id("T_spindle_degC")
    # The timeouts (real time) only end a hung attempt: a secure session opened on a busy
    # host takes seconds, and the reconnect time is counted on the link's clock, not here.
    driver = make_driver(certs, restart_server.url, request_timeout_s=2.0)
    clock = VirtualClock()  # the backoff's clock: the retries counted, not the machine's speed
    link = DriverLink("opcua", driver, clock, timeout_s=10.0, backoff_min_s=0.1, backoff_max_s=0.4)

    async def scenario() -> tuple[float, list[dict[str, float]]]:
        await link.open()
        assert await link.read([point]) == {point: 31.25}
        await asyncio.to_thread(restart_server.stop)
        with pytest.raises(DriverDisconnectedError):
            await driver.read([point])
        down = [await link.read([point]) for _ in range(3)]
        assert await link.write({restart_server.node_id("comp_x_um"): 1.0}) is False
        await asyncio.to_thread(restart_server.start)
        reconnect_s = await seconds_until_read(link, clock, [point])
        assert await link.read([point]) == {point: 31.25}
        await link.close()
        return reconnect_s, down

    reconnect_s, down = asyncio.run(scenario())
    assert down == [{}, {}, {}] and reconnect_s < 5.0 and link.reconnects == 1


def test_asyncua_logs_nothing_above_debug(certs, server):
    """Connecting, 5 reads and a close put no asyncua record in compd's log (it logs each read at INFO)."""

    async def scenario() -> None:
        driver = await opened(make_driver(certs, server.url))
        for _ in range(5):
            await driver.read([server.node_id("T_spindle_degC")])
        await driver.close()

    # What reaches the root logger's handlers is what the journal shows. (pytest >= 9.2's
    # caplog also listens on non-propagating loggers, so it would see what stops at asyncua's.)
    reached: list[logging.LogRecord] = []
    handler = logging.Handler(logging.DEBUG)
    handler.emit = reached.append  # type: ignore[method-assign]
    root = logging.getLogger()
    root.addHandler(handler)
    try:
        with structlog.testing.capture_logs() as events:
            asyncio.run(scenario())
    finally:
        root.removeHandler(handler)
    assert [r.getMessage() for r in reached if r.name.startswith("asyncua")] == []
    assert all(e["log_level"] == "debug" for e in events)


#: Variant types and values a Double variable must never be read as: not a number, or many.
_NOT_NUMBERS = st.one_of(
    st.text(max_size=20).map(lambda v: ua.Variant(v, ua.VariantType.String)),
    st.binary(max_size=20).map(lambda v: ua.Variant(v, ua.VariantType.ByteString)),
    st.datetimes().map(lambda v: ua.Variant(v, ua.VariantType.DateTime)),
    st.uuids().map(lambda v: ua.Variant(v, ua.VariantType.Guid)),
    st.text(max_size=10).map(
        lambda v: ua.Variant(ua.LocalizedText(v), ua.VariantType.LocalizedText)
    ),
    st.text(max_size=10).map(
        lambda v: ua.Variant(ua.QualifiedName(v, 0), ua.VariantType.QualifiedName)
    ),
    st.integers(0, 2**16).map(lambda v: ua.Variant(ua.NodeId(v, 0), ua.VariantType.NodeId)),
    st.lists(st.floats(), max_size=4).map(lambda v: ua.Variant(v, ua.VariantType.Double)),
    st.lists(st.integers(-(2**31), 2**31 - 1), max_size=4).map(
        lambda v: ua.Variant(v, ua.VariantType.Int32)
    ),
    st.just(ua.Variant()),
)
#: Numbers of another type than the variable's: still one number, read as a float.
_OTHER_NUMBERS = st.one_of(
    st.integers(-(2**63), 2**63 - 1).map(lambda v: ua.Variant(v, ua.VariantType.Int64)),
    st.integers(0, 2**64 - 1).map(lambda v: ua.Variant(v, ua.VariantType.UInt64)),
    st.floats(width=32).map(lambda v: ua.Variant(v, ua.VariantType.Float)),
    st.booleans().map(lambda v: ua.Variant(v, ua.VariantType.Boolean)),
)


def test_a_variable_of_the_wrong_variant_type_is_a_protocol_error(certs, server):
    """A Double variable holding a string, a date, an array or nothing is a DriverProtocolError; numbers are floats."""
    node = server.node_id("T_fuzzed_degC")
    driver = make_driver(certs, server.url)
    with asyncio.Runner() as runner:
        runner.run(driver.open())

        @settings(max_examples=40, deadline=None)
        @given(variant=_NOT_NUMBERS | _OTHER_NUMBERS)
        def check(variant: ua.Variant) -> None:
            server.set_variant("T_fuzzed_degC", variant)
            if variant.VariantType in NUMERIC_TYPES and not variant.is_array:
                (value,) = runner.run(driver.read([node])).values()
                assert type(value) is float
            else:
                with pytest.raises(DriverProtocolError, match="not a number"):
                    runner.run(driver.read([node]))

        try:
            check()
        finally:
            runner.run(driver.close())
            server.set_variant("T_fuzzed_degC", ua.Variant(20.0, ua.VariantType.Double))
