"""Where a driver instance reaches: one name per device, so that overlap checks span driver entries.

A written value's cells (:func:`compd.drivers.base.write_footprint`) start
with the endpoint they live on, so that two driver entries reaching one PLC
are checked as one device:

- TCP (Modbus, a gateway over Modbus TCP, OPC UA): the host and the port.
  ``localhost``, ``127.0.0.1``, ``::1`` and every other loopback address are
  one host (a local server usually listens on all of them); an IP address is
  compared in its canonical spelling (``::ffff:10.0.0.5`` is ``10.0.0.5``);
  any other name is resolved once, waiting at most :data:`RESOLVE_WAIT_S`
  (a name that does not resolve in time is compared as written, in lower case);
- a serial line: the device file with its links followed
  (``/dev/serial/by-id/...`` is the ``/dev/ttyUSB0`` it points to);
- CAN: the python-can interface and channel.
"""

from __future__ import annotations

import ipaddress
import os
import socket
import threading
from collections.abc import Hashable
from functools import cache

#: The key of every loopback host.
LOOPBACK = "loopback"
#: Names that mean this machine without asking a resolver.
_LOCAL_NAMES = frozenset({"localhost", "localhost.localdomain", "ip6-localhost", "ip6-loopback"})
#: The longest a host name's resolution may hold up ``check-config`` (s).
RESOLVE_WAIT_S = 0.3
#: Modbus unit ids: 0 (broadcast on a serial line) to 247.
MODBUS_UNITS = range(248)

Endpoint = tuple[Hashable, ...]


def tcp_endpoint(kind: str, host: str, port: int) -> Endpoint:
    """A TCP server: ``(kind, host key, port)``; ``kind`` names the protocol spoken there."""
    return (kind, host_key(host), port)


def serial_endpoint(path: str) -> Endpoint:
    """A serial line, by its device file with links followed."""
    return ("serial", os.path.realpath(path))


def can_endpoint(interface: str, channel: str) -> Endpoint:
    """A CAN bus: the python-can interface and channel."""
    return ("can", interface, channel)


def modbus_units(device: int, *, serial: bool, separate: bool = False) -> range:
    """The unit ids a request to ``device`` may reach.

    On a serial line unit ids are addresses on the wire: its own, or every
    one for the broadcast id 0. Behind Modbus TCP many servers ignore the
    unit id: every one, unless the config says the server keeps them
    ``separate`` (a gateway to a serial bus).
    """
    if (serial and device != 0) or (not serial and separate):
        return range(device, device + 1)
    return MODBUS_UNITS


@cache
def host_key(host: str) -> str:
    """One spelling per host: loopback, an IP address in canonical form, or the name in lower case."""
    name = host.strip().lower().rstrip(".")
    if name.startswith("[") and name.endswith("]"):
        name = name[1:-1]
    literal = _ip_key(name)
    if literal is not None:
        return literal
    if name in _LOCAL_NAMES or name.endswith(".localhost"):
        return LOOPBACK
    addresses = {key for key in map(_ip_key, _resolve(name)) if key is not None}
    return min(addresses) if addresses else name


def _ip_key(text: str) -> str | None:
    """An IP address's key (loopback and the unspecified address: :data:`LOOPBACK`), or None for a name."""
    try:
        ip = ipaddress.ip_address(text.partition("%")[0])
    except ValueError:
        return None
    if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:
        ip = ip.ipv4_mapped
    return LOOPBACK if ip.is_loopback or ip.is_unspecified else ip.compressed


def _resolve(name: str) -> list[str]:
    """The addresses ``name`` resolves to within :data:`RESOLVE_WAIT_S`, else none."""
    found: list[str] = []

    def lookup() -> None:
        try:
            infos = socket.getaddrinfo(name, None, type=socket.SOCK_STREAM)
        except (OSError, UnicodeError):
            return
        found.extend(str(info[4][0]) for info in infos)

    # A resolver that does not answer must not hold up the check: the thread is left to finish.
    worker = threading.Thread(target=lookup, name=f"resolve {name}", daemon=True)
    worker.start()
    worker.join(RESOLVE_WAIT_S)
    return list(found) if not worker.is_alive() else []
