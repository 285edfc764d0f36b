"""The simulated PLC's OPC UA server: compd's ``type: opcua`` driver connects to it as to a machine.

An asyncua server in the caller's event loop, listening at ``settings.url``,
with one Double variable per address the config reads (read-only) or writes
(writable). A NodeId address (``ns=2;s=Machine.T_spindle``, ``ns=3;i=1001``)
becomes that very node, under the object ``Objects/1:SimulatedPLC``; a browse
path (``0:Objects/2:Machine/2:T_spindle``) becomes the objects along it and
a variable at its end. Namespaces ``urn:compd:sim:ns2``, ``...ns3`` are
registered so every ``ns=N`` named exists.

Security mirrors the settings the driver connects with, so a fresh demo
machine works with nothing but its config: only ``security.policy`` /
``security.mode`` are offered (no security with ``security: none``);
missing certificates are generated (:mod:`compd.sim.plc.opcua_security`); the one
client certificate named in the settings is trusted, no other; and only
``username`` with the password from ``password_file``/``password_env`` logs
in (read exactly as the driver reads it).

``publish`` sets the values straight in the address space (no request, no
task: about 1.5 us a value). Client writes reach ``on_write`` through asyncua's
``PostWrite`` server callback, once per written value that the server took.
``stop`` closes the listener and every connection but keeps the address
space; ``start`` again listens anew with the same certificates: a PLC
restart in a few milliseconds, where building the server takes seconds.
"""

from __future__ import annotations

import asyncio
import logging
import socket
import time
from collections.abc import Mapping, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, cast
from urllib.parse import urlparse

import structlog
from asyncua import ua
from asyncua.common.callback import CallbackType, ServerItemCallback
from asyncua.server.address_space import AttributeValue
from asyncua.server.server import Server
from asyncua.ua.attribute_ids import AttributeIds
from asyncua.ua.object_ids import ObjectIds
from asyncua.ua.status_codes import StatusCodes
from asyncua.ua.uaerrors import UaStatusCodeError

from compd.drivers.opcua.security import read_password
from compd.drivers.opcua.settings import OpcUaSettings
from compd.errors import DriverError
from compd.files.yamlplace import resolve_path
from compd.sim.plc.opcua_security import (
    POLICIES,
    SERVER_URI,
    OneUser,
    TrustOne,
    ensure_client_certificate,
    ensure_server_certificate,
)
from compd.sim.plc.server import WriteSink

log = structlog.get_logger("compd.sim.plc.opcua")

#: Namespace ``N`` (N >= 2) registered for ``ns=N`` in addresses.
NAMESPACE_URI = "urn:compd:sim:ns{}"
#: Parent object of the variables addressed by NodeId.
PLC_OBJECT = ua.NodeId(ua.String("SimulatedPLC"), ua.Int16(1))

_DOUBLE = ua.VariantType.Double
_GOOD = ua.StatusCode(ua.UInt32(StatusCodes.Good))
#: Path separators a created node can satisfy: ``/`` (hierarchical) and ``.`` (aggregates).
_PATH_REFERENCES = {
    ua.NodeId(ua.Int32(ObjectIds.HierarchicalReferences)),
    ua.NodeId(ua.Int32(ObjectIds.Aggregates)),
    ua.NodeId(ua.Int32(ObjectIds.HasComponent)),
}


def parse_address(address: str) -> ua.NodeId | ua.RelativePath:
    """The NodeId or browse path an address names, as the driver reads it; ValueError says why not."""
    if "/" in address:
        try:
            path = ua.RelativePath.from_string("/" + address.lstrip("/"))
        except Exception as exc:  # asyncua raises several types for a bad path
            raise ValueError(
                f"OPC UA address {address!r} is not a browse path like "
                f"0:Objects/2:Machine/2:T_spindle ({exc})"
            ) from None
        for element in path.Elements:
            if element.IsInverse or element.ReferenceTypeId not in _PATH_REFERENCES:
                raise ValueError(
                    f"OPC UA address {address!r}: the simulated PLC builds paths of '/' and '.' "
                    "steps only; write it as 0:Objects/2:Machine/2:Name"
                )
        return path
    try:
        node_id = ua.NodeId.from_string(address)
    except Exception as exc:
        raise ValueError(
            f"OPC UA address {address!r} is neither a NodeId (ns=2;s=Name) nor a "
            f"browse path (0:Objects/2:Machine/2:Name): {exc}"
        ) from None
    if node_id.NamespaceIndex == 0:
        raise ValueError(
            f"OPC UA address {address!r} is in namespace 0, which belongs to the OPC UA "
            "standard: give the simulated PLC's variables ns=2 or above (ns=2;s=Machine.Name)"
        )
    return node_id


class OpcUaPlcServer:
    """The simulated controller behind one ``type: opcua`` driver instance; see the module docstring."""

    settings_model = OpcUaSettings

    def __init__(
        self,
        settings: OpcUaSettings,
        *,
        inputs: Sequence[str],
        outputs: Sequence[str],
        on_write: WriteSink,
        base_dir: Path,
    ) -> None:
        self.settings = settings
        self._on_write = on_write
        self._base_dir = base_dir
        url = urlparse(settings.url)
        if url.hostname is None or url.port is None:
            raise ValueError(
                f"OPC UA url {settings.url!r} has no host and port for the simulated PLC "
                "to listen at: write opc.tcp://127.0.0.1:4840/compd/"
            )
        self._outputs = set(outputs)
        #: Every address, in order, with what it names.
        self._targets = {a: parse_address(a) for a in dict.fromkeys([*inputs, *outputs])}
        self._values: dict[str, float] = dict.fromkeys(self._targets, 0.0)
        self._attrs: dict[str, AttributeValue] = {}
        self._written: dict[ua.NodeId, str] = {}
        self._server: Server | None = None
        self._listening = False
        self._tasks: set[asyncio.Task[None]] = set()
        #: Seconds the last ``start`` took (building the server the first time, then listening).
        self.last_start_s = 0.0

    # -- PlcServer ----------------------------------------------------------

    async def start(self) -> None:
        if self._listening:
            return
        t0 = time.perf_counter()
        if self._server is None:
            self._check_port()  # before the seconds of building, and asyncua's traceback
            server = await self._build()
            try:
                await server.start()
            except OSError as exc:  # asyncua has already stopped its internal server
                raise OSError(
                    f"simulated OPC UA server cannot listen at {self.settings.url}: {exc}; "
                    "is another server on that port?"
                ) from exc
            self._server = server
        else:
            try:
                await self._server.bserver.start()  # type: ignore[union-attr]
            except OSError as exc:
                raise OSError(
                    f"simulated OPC UA server cannot listen again at {self.settings.url}: {exc}"
                ) from exc
        self._listening = True
        self.last_start_s = time.perf_counter() - t0
        log.info(
            "simulated OPC UA server listening",
            url=self.settings.url,
            security=None if self.settings.security is None else self.settings.security.mode,
            start_ms=round(self.last_start_s * 1e3, 1),
        )

    async def stop(self) -> None:
        if not self._listening or self._server is None or self._server.bserver is None:
            return
        self._listening = False
        try:
            await self._server.bserver.stop()
        except Exception as exc:  # stop never raises: the clients are gone either way
            log.warning("simulated OPC UA server stop failed", error=repr(exc))

    def publish(self, values: Mapping[str, float]) -> None:
        now = cast(ua.DateTime, datetime.now(UTC))
        for address, raw in values.items():
            if address not in self._values:
                raise KeyError(
                    f"simulated OPC UA server at {self.settings.url} serves no address {address!r}; "
                    "publish only the inputs and outputs it was built with"
                )
            self._values[address] = raw
            attr = self._attrs.get(address)
            if attr is None:  # not started yet: the value is served from the first start
                continue
            value = ua.DataValue(ua.Variant(float(raw), _DOUBLE, None, False), _GOOD, now, now)
            attr.value = value
            if attr.datachange_callbacks:  # a client subscribed: notify it as asyncua would
                self._notify(attr, value)

    # -- building -----------------------------------------------------------

    def _check_port(self) -> None:
        url = urlparse(self.settings.url)
        with socket.socket(
            socket.AF_INET6 if ":" in str(url.hostname) else socket.AF_INET
        ) as probe:
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as asyncio's server does
            try:
                probe.bind((url.hostname, url.port))
            except OSError as exc:
                raise OSError(
                    f"simulated OPC UA server cannot listen at {self.settings.url}: {exc.strerror}; "
                    "is another server on that port? Change the port in the driver's url"
                ) from exc

    async def _build(self) -> Server:
        """A configured server with every variable; certificates generated where missing."""
        settings = self.settings
        self._attrs.clear()
        self._written.clear()
        # asyncua's server logs every request at INFO: at 3600x that floods compd's log.
        asyncua_log = logging.getLogger("asyncua.server")
        if asyncua_log.level == logging.NOTSET:  # a level set on purpose stays
            asyncua_log.setLevel(logging.WARNING)
        users = None
        if settings.username:
            users = OneUser(settings.username, self._password())
        server = Server(user_manager=users)
        await server.init()
        server.disable_clock()  # a 1 s real-time task the simulated PLC does not need
        server.set_endpoint(settings.url)
        server.set_server_name("compd simulated PLC")
        security = settings.security
        if security is None:
            server.set_security_policy([ua.SecurityPolicyType.NoSecurity])
            await server.set_application_uri(SERVER_URI)
        else:
            server_der, server_key, server_uri = ensure_server_certificate(
                self._path(security.server_certificate), SERVER_URI, urlparse(settings.url).hostname
            )
            client_cert = ensure_client_certificate(
                self._path(security.certificate),
                self._path(security.private_key),
                security.application_uri,
            )
            server.set_security_policy([POLICIES[(security.policy, security.mode)]])
            await server.set_application_uri(server_uri)
            await server.load_certificate(server_der, format="der")
            await server.load_private_key(server_key, format="pem")
            server.set_certificate_validator(TrustOne(client_cert))
        tokens: list[type] = [ua.UserNameIdentityToken if users else ua.AnonymousIdentityToken]
        server.set_identity_tokens(tokens)
        await self._add_variables(server)
        server.subscribe_server_callback(CallbackType.PostWrite, self._post_write)
        return server

    def _password(self) -> str:
        """The password exactly as the driver reads it (file or environment), never logged."""
        try:
            return str(read_password(self.settings, self._base_dir))
        except DriverError as exc:
            raise RuntimeError(f"simulated OPC UA server: {exc}") from None

    def _path(self, name: str) -> Path:
        return resolve_path(name, self._base_dir)

    async def _add_variables(self, server: Server) -> None:
        """Namespaces, then the NodeId variables, then the browse paths (their objects made as needed)."""
        highest = 1
        for target in self._targets.values():
            if isinstance(target, ua.NodeId):
                highest = max(highest, target.NamespaceIndex)
            else:
                highest = max([highest, *(e.TargetName.NamespaceIndex for e in target.Elements)])
        for ns in range(len(await server.get_namespace_array()), highest + 1):
            await server.register_namespace(NAMESPACE_URI.format(ns))
        aspace = server.iserver.aspace
        nodes: dict[str, ua.NodeId] = {}
        plc = None
        for address, target in self._targets.items():
            if not isinstance(target, ua.NodeId):
                continue
            if target in aspace:
                raise RuntimeError(
                    f"OPC UA address {address!r} names a node the server already has; "
                    "choose another NodeId (ns=2;s=Machine.Name)"
                )
            if plc is None:
                plc = await server.nodes.objects.add_object(
                    PLC_OBJECT, ua.QualifiedName("SimulatedPLC", 1)
                )
            name = ua.QualifiedName(str(target.Identifier), target.NamespaceIndex)
            nodes[address] = await self._variable(plc, target, name, address)
        made: dict[ua.NodeId, str] = {}
        for address, target in self._targets.items():
            if isinstance(target, ua.RelativePath):
                nodes[address] = await self._path_variable(server, address, target, made)
        for address, node_id in nodes.items():
            self._attrs[address] = aspace[node_id].attributes[AttributeIds.Value]
            if address in self._outputs:
                self._written[node_id] = address

    async def _variable(
        self, parent: Any, node_id: ua.NodeId, name: ua.QualifiedName, address: str
    ) -> ua.NodeId:
        initial = ua.Variant(float(self._values[address]), _DOUBLE)
        node = await parent.add_variable(node_id, name, initial)
        if address in self._outputs:
            await node.set_writable()
        return node.nodeid  # type: ignore[no-any-return]

    async def _path_variable(
        self, server: Server, address: str, path: ua.RelativePath, made: dict[ua.NodeId, str]
    ) -> ua.NodeId:
        """Walk the path from the root, adding each missing object and the variable at its end."""
        node = server.nodes.root
        walked = ""
        last = len(path.Elements) - 1
        for i, element in enumerate(path.Elements):
            name = element.TargetName
            walked += f"/{name.NamespaceIndex}:{name.Name}"
            try:
                child = await node.get_child(name)
            except UaStatusCodeError:
                child = None
            if child is not None:
                if i == last and made.get(child.nodeid) is None:
                    raise RuntimeError(
                        f"OPC UA address {address!r} names a node the server already has; "
                        "put the variable under your own object (0:Objects/2:Machine/2:Name)"
                    )
                node = child
                continue
            if name.NamespaceIndex == 0:
                raise RuntimeError(
                    f"OPC UA address {address!r}: {walked} is not a standard node of namespace 0; "
                    "name the simulated PLC's own nodes in ns 2 or above (2:Machine)"
                )
            node_id = ua.NodeId(ua.String(f"compd.sim:{walked.lstrip('/')}"), name.NamespaceIndex)
            if node_id in server.iserver.aspace:
                raise RuntimeError(
                    f"OPC UA address {address!r}: node {node_id.to_string()} exists already"
                )
            if i < last:
                node = await node.add_object(node_id, name)
            else:
                made[await self._variable(node, node_id, name, address)] = address
                return node_id
        return node.nodeid

    # -- writes from clients ------------------------------------------------

    async def _post_write(self, event: ServerItemCallback, _: Any) -> None:
        """Report each value a client wrote and the server took, once (internal writes are not reported)."""
        if not event.is_external:
            return
        request = event.request_params.NodesToWrite
        for write, status in zip(request, event.response_params, strict=True):
            address = self._written.get(write.NodeId)
            if address is None or write.AttributeId != AttributeIds.Value or not status.is_good():
                continue
            raw = float(write.Value.Value.Value)
            self._values[address] = raw
            try:
                self._on_write(address, raw)
            except Exception:  # the machine's fault: the PLC goes on serving
                log.exception("on_write failed", address=address)

    def _notify(self, attr: AttributeValue, value: ua.DataValue) -> None:
        try:
            loop = asyncio.get_running_loop()
        except RuntimeError:  # published outside the loop: no client can be listening
            return
        task = loop.create_task(_run_callbacks(attr, value))
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)


async def _run_callbacks(attr: AttributeValue, value: ua.DataValue) -> None:
    for handle, callback in list(attr.datachange_callbacks.items()):
        try:
            await callback(handle, value)
        except Exception:
            log.exception("OPC UA data change callback failed")
