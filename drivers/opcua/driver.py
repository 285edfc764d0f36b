"""OPC UA driver: polls variables of an OPC UA server and writes offsets to it (asyncua).

A point's address is a NodeId string (``ns=2;s=Machine.T_spindle``,
``i=2258``) or a browse path from the root node
(``0:Objects/2:Machine/2:T_spindle``). Addresses are resolved once per
connection, together with each node's data type, in one TranslateBrowsePaths
and one Read call; after that every tick is ONE Read service call for all
requested nodes (the loop polls; a 1 s subscription would add up to a period
of latency and its own reconnect logic).

Values are typed by the server (:mod:`compd.drivers.opcua.values`): reads
give floats, writes go out with each node's own variant type, integers
range-checked and never wrapped.

Security follows the settings and is on unless switched off in words:
``security`` is required, its mode defaults to ``SignAndEncrypt`` (or
``Sign``) with ``Basic256Sha256`` (or ``Aes256_Sha256_RsaPss``), the client's
application certificate and key, and the server certificate the client
trusts. ``security: none`` must be written out, and is refused with a
password (it would cross the wire in clear). Before each secured connect
the server's endpoints (readable without security) are checked: a server
presenting another certificate is refused at once as "not trusted", where
the secured handshake alone would only time out. A username's password
comes from a file or an environment variable; secrets are never logged or
put into error messages (:mod:`compd.drivers.opcua.security`).
"""

from __future__ import annotations

import asyncio
import re
from collections.abc import Callable, Hashable, Mapping, Sequence
from pathlib import Path

import structlog
from asyncua import ua
from asyncua.client.client import Client
from asyncua.common.node import Node
from asyncua.ua.attribute_ids import AttributeIds
from asyncua.ua.status_codes import StatusCodes
from asyncua.ua.uaerrors import UaError, UaStatusCodeError, UaStringParsingError

from compd.drivers.base import HostProblem, RawReading
from compd.drivers.library_logs import quiet_library
from compd.drivers.opcua.security import (
    REFUSALS,
    certificate_der,
    certificate_uri,
    check_endpoints,
    check_files,
    read_password,
    settings_file,
)
from compd.drivers.opcua.settings import POLICIES, OpcUaSecurity, OpcUaSettings
from compd.drivers.opcua.values import NUMERIC_TYPES, to_float, to_variant, variant_type
from compd.errors import (
    DriverDisconnectedError,
    DriverError,
    DriverProtocolError,
    DriverTimeoutError,
)

log = structlog.get_logger("compd.drivers.opcua.driver")
quiet_library("asyncua")  # a line per read at INFO, per dropped session at WARNING


#: Status codes that mean the session or channel is gone: reconnect.
_GONE = {
    StatusCodes.BadSessionClosed,
    StatusCodes.BadSessionIdInvalid,
    StatusCodes.BadSecureChannelClosed,
    StatusCodes.BadSecureChannelIdInvalid,
    StatusCodes.BadConnectionClosed,
    StatusCodes.BadServerNotConnected,
    StatusCodes.BadShutdown,
    StatusCodes.BadCommunicationError,
}


#: An address in NodeId syntax: ``[ns=N;|nsu=URI;]`` then ``i=``, ``s=``, ``g=`` or ``b=``.
_NODE_ID = re.compile(r"(ns=\d+;|nsu=[^;]+;)?[isgb]=")


def _node_id(address: str) -> ua.NodeId | None:
    """The NodeId an address names directly, or None when it is a browse path.

    NodeId syntax wins over a ``/`` in the text: SINUMERIK's string NodeIds are
    paths themselves (``ns=2;s=/Plc/DB9000.DBD10:DINT``).
    """
    if "/" in address and not _NODE_ID.match(address):
        return None
    try:
        return ua.NodeId.from_string(address)
    except (ValueError, UaError) as exc:
        raise DriverProtocolError(
            f"OPC UA address {address!r} is neither a NodeId (ns=2;s=Name) nor a "
            f"browse path (0:Objects/2:Machine/2:Name): {exc}"
        ) from exc


def _status_name(code: int) -> str:
    return ua.StatusCode(ua.UInt32(code)).name


def _good(status: ua.StatusCode | None) -> bool:
    """An absent status code means Good (OPC UA Part 6, DataValue encoding)."""
    return status is None or status.is_good()


def _name(status: ua.StatusCode | None) -> str:
    return "Good" if status is None else status.name


class OpcUaDriver:
    """One client session to one OPC UA server; see the module docstring."""

    settings_model = OpcUaSettings

    @staticmethod
    def footprint(address: str, settings: OpcUaSettings) -> frozenset[tuple[Hashable, ...]]:
        """The node on the server: a NodeId in its canonical form (``ns=2;s=X``), else the browse path.

        A NodeId and a browse path naming the same node are told apart only
        by the server: :meth:`naming` says which way an address names its
        node, and ``check-config`` refuses a mix where compd writes.
        """
        try:
            node_id = _node_id(address)
        except DriverProtocolError:  # not a NodeId: its text is all there is to compare
            node_id = None
        text = node_id.to_string() if node_id is not None else address.lstrip("/")
        return frozenset({(settings.endpoint(), "node", text)})

    @staticmethod
    def naming(address: str, settings: OpcUaSettings) -> str:
        """``a NodeId``, ``a NodeId with a namespace URI`` or ``a browse path``."""
        try:
            node_id = _node_id(address)
        except DriverProtocolError:
            node_id = None
        if node_id is None:
            return "a browse path"
        return (
            "a NodeId with a namespace URI"
            if isinstance(node_id, ua.ExpandedNodeId)
            else "a NodeId"
        )

    @staticmethod
    def reads_back(settings: OpcUaSettings) -> bool:
        """A written variable reads back the server's current value."""
        return True

    @staticmethod
    def check_host(
        settings: OpcUaSettings, *, base_dir: Path, written: Sequence[str]
    ) -> HostProblem | None:
        """Every certificate, key and password file named is there and readable."""
        return check_files(settings, base_dir)

    def __init__(
        self, settings: OpcUaSettings, *, now: Callable[[], float], base_dir: Path
    ) -> None:
        self.settings = settings
        self._now = now
        self._base_dir = base_dir
        self._client: Client | None = None
        self._lock = asyncio.Lock()
        #: Resolved per connection: address -> (node, variant type).
        self._nodes: dict[str, tuple[Node, ua.VariantType]] = {}

    # -- lifecycle ---------------------------------------------------------

    async def open(self) -> None:
        async with self._lock:
            await self._drop_client()
            if self.settings.security is not None:
                await self._check_server_endpoint(self.settings.security)
            client = Client(self.settings.url, timeout=self.settings.request_timeout_s)
            try:
                await self._configure(client)
                await client.connect()
            except asyncio.CancelledError:
                await _disconnect_quietly(client)
                raise
            except Exception as exc:
                await _disconnect_quietly(client)
                raise self._translate(exc, "connect") from exc
            self._client = client
            log.debug("opcua connected", url=self.settings.url)

    async def close(self) -> None:
        async with self._lock:
            await self._drop_client()

    async def _drop_client(self) -> None:
        client, self._client = self._client, None
        self._nodes.clear()
        if client is not None:
            await _disconnect_quietly(client)

    async def _configure(self, client: Client) -> None:
        security = self.settings.security
        if security is not None:
            cert_path = self._path(security.certificate)
            client.application_uri = security.application_uri or certificate_uri(cert_path)
            await client.set_security(
                POLICIES[security.policy],
                certificate=str(cert_path),
                private_key=str(self._path(security.private_key)),
                server_certificate=str(self._path(security.server_certificate)),
                mode=getattr(ua.MessageSecurityMode, security.mode),
            )
        if self.settings.username:
            client.set_user(self.settings.username)
            client.set_password(read_password(self.settings, self._base_dir))

    async def _check_server_endpoint(self, security: OpcUaSecurity) -> None:
        """Refuse a server that is not the trusted one, or lacks our policy, before the handshake.

        A server whose certificate differs from ``security.server_certificate``
        cannot decrypt our OpenSecureChannel and just drops it, which looks
        like a timeout (and the link's own timeout would cut any diagnosis
        made afterwards). Its endpoints, readable without security in one
        short exchange, tell at once (:func:`check_endpoints`).
        """
        trusted = certificate_der(self._path(security.server_certificate))
        probe = Client(self.settings.url, timeout=self.settings.request_timeout_s)
        try:
            async with asyncio.timeout(self.settings.request_timeout_s):
                endpoints = await probe.connect_and_get_server_endpoints()
        except asyncio.CancelledError:
            raise
        except Exception as exc:
            raise self._translate(exc, "connect (endpoints)") from exc
        finally:
            probe.disconnect_socket()
        mode = getattr(ua.MessageSecurityMode, security.mode)
        check_endpoints(self.settings.url, endpoints, trusted, POLICIES[security.policy].URI, mode)

    def _path(self, name: str) -> Path:
        return settings_file(name, self._base_dir)

    # -- read and write ----------------------------------------------------

    async def read(self, points: Sequence[str]) -> dict[str, float]:
        values: dict[str, float] = {}
        for point, result in zip(points, await self._read_values(points), strict=True):
            if not _good(result.StatusCode):
                # A bad quality (sensor fault, out of service) is no new value:
                # the signal goes stale, the rest of the batch is still good.
                log.debug("opcua bad quality", address=point, status=_name(result.StatusCode))
                continue
            values[point] = to_float(point, None if result.Value is None else result.Value.Value)
        return values

    async def read_raw(self, points: Sequence[str]) -> dict[str, RawReading]:
        """Each node's value with its variant type (``Int32 -1234``), or its bad status code."""
        readings: dict[str, RawReading] = {}
        for point, result in zip(points, await self._read_values(points), strict=True):
            variant = result.Value
            shown = "empty" if variant is None else f"{variant.VariantType.name} {variant.Value!r}"
            if not _good(result.StatusCode):
                readings[point] = RawReading(shown, None, _name(result.StatusCode))
            else:
                value = to_float(point, None if variant is None else variant.Value)
                readings[point] = RawReading(shown, value)
        return readings

    async def _read_values(self, points: Sequence[str]) -> list[ua.DataValue]:
        """Each address's DataValue, in one Read service call."""
        async with self._lock:
            client = self._connected()
            try:
                await self._resolve(client, points)
                nodes = [self._nodes[p][0].nodeid for p in points]
                results: list[ua.DataValue] = await client.uaclient.read_attributes(
                    nodes, AttributeIds.Value
                )
            except (DriverError, asyncio.CancelledError):
                raise
            except Exception as exc:
                raise self._translate(exc, "read") from exc
        return results

    async def write(self, values: Mapping[str, float]) -> None:
        if not values:
            return
        async with self._lock:
            client = self._connected()
            points = list(values)
            try:
                await self._resolve(client, points)
                # Encode every value before sending any: one bad value sends nothing.
                data = [ua.DataValue(to_variant(p, values[p], self._nodes[p][1])) for p in points]
                nodes = [self._nodes[p][0].nodeid for p in points]
                results = await client.uaclient.write_attributes(nodes, data, AttributeIds.Value)
            except (DriverError, asyncio.CancelledError):
                raise
            except Exception as exc:
                raise self._translate(exc, "write") from exc
        refused = [
            f"{p}: {status.name}"
            for p, status in zip(points, results, strict=True)
            if not status.is_good()
        ]
        if refused:
            raise DriverProtocolError(
                f"OPC UA server {self.settings.url} refused writes ({'; '.join(refused)})"
            )

    def _connected(self) -> Client:
        if self._client is None:
            raise DriverDisconnectedError(f"OPC UA driver for {self.settings.url} is not connected")
        return self._client

    async def _resolve(self, client: Client, points: Sequence[str]) -> None:
        """Find the node and data type of every new address: one call each for paths and types."""
        new = [p for p in dict.fromkeys(points) if p not in self._nodes]
        if not new:
            return
        ids: dict[str, ua.NodeId] = {}
        paths = []
        for point in new:
            node_id = _node_id(point)
            if node_id is None:
                paths.append(point)
            else:
                ids[point] = node_id
        if paths:
            relative = ["/" + p.lstrip("/") for p in paths]
            try:
                found = await client.translate_browsepaths(client.nodes.root.nodeid, relative)
            except UaStringParsingError as exc:
                raise DriverProtocolError(f"OPC UA browse path not understood: {exc}") from exc
            for point, result in zip(paths, found, strict=True):
                if not result.StatusCode.is_good() or not result.Targets:
                    raise DriverProtocolError(
                        f"OPC UA server {self.settings.url} has no node at browse path "
                        f"{point!r} ({result.StatusCode.name})"
                    )
                ids[point] = result.Targets[0].TargetId
        types = await client.uaclient.read_attributes([ids[p] for p in new], AttributeIds.DataType)
        for point, typed in zip(new, types, strict=True):
            if not _good(typed.StatusCode) or typed.Value is None:
                raise DriverProtocolError(
                    f"OPC UA server {self.settings.url} has no variable {point!r} "
                    f"({_name(typed.StatusCode)})"
                )
            data_type = typed.Value.Value
            vtype = variant_type(data_type)
            if vtype not in NUMERIC_TYPES:
                raise DriverProtocolError(
                    f"OPC UA variable {point!r} has data type {data_type.to_string()}, "
                    "not a number or Boolean"
                )
            self._nodes[point] = (client.get_node(ids[point]), vtype)

    def _translate(self, exc: BaseException, action: str) -> DriverError:
        """A compd DriverError for any library or socket failure (secrets never in the text)."""
        where = f"OPC UA server {self.settings.url}"
        if isinstance(exc, DriverError):
            return exc
        if isinstance(exc, TimeoutError | asyncio.TimeoutError):
            return DriverTimeoutError(f"{where}: no answer to {action} within the request timeout")
        if isinstance(exc, UaStatusCodeError):
            code = exc.code
            if code in REFUSALS:
                return DriverProtocolError(f"{where} {REFUSALS[code]} ({_status_name(code)})")
            if code in _GONE:
                return DriverDisconnectedError(
                    f"{where}: connection lost on {action} ({_status_name(code)})"
                )
            if code == StatusCodes.BadTimeout:
                return DriverTimeoutError(f"{where}: {action} timed out (BadTimeout)")
            return DriverProtocolError(f"{where}: {action} failed ({_status_name(code)})")
        if isinstance(exc, ConnectionError | OSError | asyncio.IncompleteReadError | EOFError):
            return DriverDisconnectedError(f"{where}: {action} failed, connection down ({exc})")
        if isinstance(exc, UaError) and "certificate mismatch" in str(exc).lower():
            return DriverProtocolError(
                f"{where} presented a certificate other than security.server_certificate: not trusted"
            )
        return DriverProtocolError(f"{where}: {action} failed ({type(exc).__name__}: {exc})")


async def _disconnect_quietly(client: Client) -> None:
    """Close session, channel and socket, bounded in time; a dead server is not an error."""
    try:
        async with asyncio.timeout(1.0):
            await client.disconnect()
    except Exception as exc:  # close never raises: the connection may already be gone
        log.debug("opcua disconnect failed", error=type(exc).__name__)
    # disconnect() may stop before the socket when the server is gone.
    client.disconnect_socket()
