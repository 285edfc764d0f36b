"""A real asyncua server for the OPC UA driver's tests, with security on.

It runs in its own thread and event loop, so one server can outlive the many
``asyncio.run`` calls of the contract suite (a secured server takes seconds to
start). It offers only ``Basic256Sha256``/``SignAndEncrypt`` and username
tokens, trusts exactly the client certificates given to it, and knows one
user. The certificates are generated per test session with asyncua's own
``cert_gen`` helpers, so nothing secret lives in the repository.
"""

from __future__ import annotations

import asyncio
import socket
import threading
from collections.abc import Coroutine
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from asyncua import Server, ua
from asyncua.crypto import cert_gen
from asyncua.crypto.permission_rules import User, UserRole
from asyncua.crypto.truststore import TrustStore
from asyncua.crypto.validator import CertificateValidator, CertificateValidatorOptions
from cryptography import x509
from cryptography.hazmat.primitives.serialization import Encoding
from cryptography.x509.oid import ExtendedKeyUsageOID

from tests.ports import free_port

NAMESPACE_URI = "urn:compd:test:machine"
SERVER_URI = "urn:compd:test:server"
USERNAME = "compd"
PASSWORD = "correct horse battery staple"

#: Variables under ``Objects/Machine``: name -> (variant type, initial value, writable).
VARIABLES: dict[str, tuple[ua.VariantType, Any, bool]] = {
    "T_spindle_degC": (ua.VariantType.Double, 31.25, False),
    "T_bed_degC": (ua.VariantType.Float, 22.5, False),
    "spindle_rpm": (ua.VariantType.UInt16, 12000, False),
    "power_w": (ua.VariantType.Int32, -1500, False),
    "running": (ua.VariantType.Boolean, True, False),
    "label": (ua.VariantType.String, "not a number", False),
    "T_faulty_degC": (ua.VariantType.Double, 99.0, False),  # quality set Bad at start
    "T_fuzzed_degC": (ua.VariantType.Double, 20.0, False),  # holds any variant (set_variant)
    "comp_x_um": (ua.VariantType.Double, 0.0, True),
    "comp_y_0p1um": (ua.VariantType.Int16, 0, True),
    "comp_z_0p1um": (ua.VariantType.Int32, 0, True),
    "status_word": (ua.VariantType.UInt16, 0, True),
    "heartbeat": (ua.VariantType.Boolean, False, True),
}

#: The string identifier of a node named like a SINUMERIK OPC UA server's PLC variables.
SINUMERIK_DBD = "/Plc/DB9000.DBD10:DINT"


@dataclass(frozen=True)
class Certificates:
    """PEM files for the server, a trusted client and an untrusted (rogue) client."""

    server_cert: Path
    server_key: Path
    client_cert: Path
    client_key: Path
    rogue_cert: Path
    rogue_key: Path
    trust_dir: Path
    client_uri: str


def _app_certificate(
    directory: Path, name: str, uri: str, usage: x509.ObjectIdentifier
) -> tuple[Path, Path]:
    key = cert_gen.generate_private_key()
    cert = cert_gen.generate_self_signed_app_certificate(
        key,
        name,
        {},
        [x509.UniformResourceIdentifier(uri), x509.DNSName(socket.gethostname())],
        extended=[usage],
        days=2,
    )
    cert_path, key_path = directory / f"{name}.pem", directory / f"{name}.key.pem"
    cert_path.write_bytes(cert.public_bytes(Encoding.PEM))
    key_path.write_bytes(cert_gen.dump_private_key_as_pem(key))
    return cert_path, key_path


def make_certificates(directory: Path) -> Certificates:
    """Generate the three self-signed application certificates under ``directory``."""
    client_uri = "urn:compd:test:client"
    server_cert, server_key = _app_certificate(
        directory, "server", SERVER_URI, ExtendedKeyUsageOID.SERVER_AUTH
    )
    client_cert, client_key = _app_certificate(
        directory, "client", client_uri, ExtendedKeyUsageOID.CLIENT_AUTH
    )
    rogue_cert, rogue_key = _app_certificate(
        directory, "rogue", client_uri, ExtendedKeyUsageOID.CLIENT_AUTH
    )
    trust_dir = directory / "trusted"
    trust_dir.mkdir()
    (trust_dir / "client.der").write_bytes(
        x509.load_pem_x509_certificate(client_cert.read_bytes()).public_bytes(Encoding.DER)
    )
    return Certificates(
        server_cert,
        server_key,
        client_cert,
        client_key,
        rogue_cert,
        rogue_key,
        trust_dir,
        client_uri,
    )


class _Users:
    """Exactly one user, :data:`USERNAME` with :data:`PASSWORD`; anything else is refused."""

    def get_user(
        self, iserver: Any, username: Any = None, password: Any = None, certificate: Any = None
    ) -> User | None:
        if username == USERNAME and password == PASSWORD:
            return User(role=UserRole.User)
        return None


class OpcUaTestServer:
    """A secured asyncua server on 127.0.0.1 in a background thread; ``start``/``stop`` block."""

    def __init__(self, certs: Certificates, port: int | None = None) -> None:
        self.certs = certs
        self.port = port if port is not None else free_port()
        self.url = f"opc.tcp://127.0.0.1:{self.port}/compd/"
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, daemon=True)
        self._thread.start()
        self._server: Server | None = None
        self.nodes: dict[str, Any] = {}
        self.namespace_index = 0
        self._garbage: list[asyncio.Server] = []

    def _call(self, coro: Coroutine[Any, Any, Any], timeout_s: float = 30.0) -> Any:
        return asyncio.run_coroutine_threadsafe(coro, self._loop).result(timeout_s)

    def node_id(self, name: str) -> str:
        """The string NodeId of variable ``name``, e.g. ``ns=2;s=Machine.comp_x_um``."""
        return f"ns={self.namespace_index};s=Machine.{name}"

    def start(self) -> None:
        self._call(self._start())

    def stop(self) -> None:
        if self._server is not None:
            self._call(self._server.stop())
            self._server = None

    def shutdown(self) -> None:
        """Stop the server and its thread."""
        self.stop()
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(5.0)

    def value(self, name: str) -> Any:
        """The variable's current value, as the server holds it."""
        return self._call(self.nodes[name].read_value())

    def set_value(self, name: str, value: Any) -> None:
        vtype = VARIABLES[name][0]
        self._call(self.nodes[name].write_value(ua.Variant(value, vtype)))

    def set_variant(self, name: str, variant: ua.Variant) -> None:
        """Serve ``variant`` as variable ``name``'s value, of its data type or not (a server breaking its own model).

        asyncua refuses to store a value of another type than the one held,
        so the value is served through the address space's read callback.
        """
        assert self._server is not None
        nodeid, value = self.nodes[name].nodeid, ua.DataValue(variant)

        async def serve() -> None:
            aspace = self._server.iserver.aspace  # type: ignore[union-attr]
            aspace.set_attribute_value_callback(nodeid, ua.AttributeIds.Value, lambda *_: value)

        self._call(serve())

    def proxy(self) -> TcpProxy:
        """A started TCP forwarder to this server, run on the server's loop; break it to cut the link."""
        proxy = TcpProxy(self.port, self._call)
        self._call(proxy.start())
        return proxy

    def garbage_port(self) -> int:
        """Port of a listener that answers every request with bytes that are not OPC UA."""

        async def answer(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            while await reader.read(65536):
                writer.write(b"ACKF\x10\x00\x00\x00garbage!" + bytes(range(40)))
                await writer.drain()
            writer.close()

        async def listen() -> int:
            listener = await asyncio.start_server(answer, "127.0.0.1", 0)
            self._garbage.append(listener)
            return int(listener.sockets[0].getsockname()[1])

        return int(self._call(listen()))

    async def _start(self) -> None:
        server = Server(user_manager=_Users())
        await server.init()
        server.set_endpoint(self.url)
        await server.set_application_uri(SERVER_URI)
        server.set_security_policy([ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt])
        server.set_identity_tokens([ua.UserNameIdentityToken])
        await server.load_certificate(str(self.certs.server_cert))
        await server.load_private_key(str(self.certs.server_key))
        store = TrustStore([self.certs.trust_dir], [])
        await store.load()
        server.set_certificate_validator(
            CertificateValidator(
                CertificateValidatorOptions.TRUSTED_VALIDATION
                | CertificateValidatorOptions.PEER_CLIENT,
                store,
            )
        )
        self.namespace_index = await server.register_namespace(NAMESPACE_URI)
        ns = self.namespace_index
        machine = await server.nodes.objects.add_object(
            ua.NodeId("Machine", ns), ua.QualifiedName("Machine", ns)
        )
        for name, (vtype, initial, writable) in VARIABLES.items():
            node = await machine.add_variable(
                ua.NodeId(f"Machine.{name}", ns),
                ua.QualifiedName(name, ns),
                ua.Variant(initial, vtype),
            )
            if writable:
                await node.set_writable()
            self.nodes[name] = node
        # A SINUMERIK-style string NodeId, a path itself: a PLC data block double word.
        self.nodes["sinumerik_dbd"] = await machine.add_variable(
            ua.NodeId(SINUMERIK_DBD, ns),
            ua.QualifiedName("DB9000.DBD10", ns),
            ua.Variant(0, ua.VariantType.Int32),
        )
        await self.nodes["sinumerik_dbd"].set_writable()
        await self.nodes["T_faulty_degC"].write_value(
            ua.DataValue(
                ua.Variant(99.0, ua.VariantType.Double),
                StatusCode=ua.StatusCode(ua.StatusCodes.BadSensorFailure),
            )
        )
        await server.start()
        self._server = server


class TcpProxy:
    """Forwards 127.0.0.1:``port`` to the server; :meth:`cut` drops every connection and the listener.

    The contract suite's ``break_connection``: the client sees its link go
    down exactly as when a cable is pulled or the server dies, while the
    shared server goes on serving the other tests.
    """

    def __init__(self, target_port: int, call: Any) -> None:
        self.target_port = target_port
        self._call = call
        self._listener: asyncio.Server | None = None
        self._writers: list[asyncio.StreamWriter] = []
        self.port = 0

    @property
    def url(self) -> str:
        return f"opc.tcp://127.0.0.1:{self.port}/compd/"

    async def start(self) -> None:
        self._listener = await asyncio.start_server(self._accept, "127.0.0.1", 0)
        self.port = self._listener.sockets[0].getsockname()[1]

    def cut(self) -> None:
        self._call(self._cut())

    async def _cut(self) -> None:
        if self._listener is not None:
            self._listener.close()
        for writer in self._writers:
            writer.transport.abort()
        self._writers.clear()

    async def _accept(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        up_reader, up_writer = await asyncio.open_connection("127.0.0.1", self.target_port)
        self._writers += [writer, up_writer]
        await asyncio.gather(_pump(reader, up_writer), _pump(up_reader, writer))


async def _pump(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
    try:
        while data := await reader.read(65536):
            writer.write(data)
            await writer.drain()
    except (ConnectionError, OSError):
        pass
    finally:
        writer.transport.abort()
