"""Where a driver instance reaches: one name per device, so that overlap checks span driver entries.

A written value's cells (:func:`compd.drivers.base.write_footprint`) start
with the endpoint they live on, so that two driver entries reaching one PLC
are checked as one device:

- TCP (Modbus, a gateway over Modbus TCP, OPC UA): the host and the port.
  This machine is one host however it is named (a local server usually
  listens on all its addresses): ``localhost``, ``127.0.0.1``, ``::1`` and
  every other loopback address, ``0.0.0.0`` and ``::``, every address of a
  local interface (:func:`local_addresses`) and any name that resolves to
  one of them; another IP address is compared in its canonical spelling
  (``::ffff:10.0.0.5`` is ``10.0.0.5``); any other name is resolved once,
  waiting at most :data:`RESOLVE_WAIT_S` (a name that does not resolve in
  time is compared as written, in lower case);
- a serial line: the device it opens (:class:`SerialLine`): a device file's
  major and minor numbers, so a second node of the same device (``mknod``)
  or another path to it (``/dev/serial/by-id/...`` for ``/dev/ttyUSB0``) is
  the same line; a path that is no device file (not plugged in now) is
  compared with its links followed;
- CAN: the python-can interface and channel.
"""

from __future__ import annotations

import ipaddress
import os
import socket
import stat
import threading
from collections.abc import Hashable
from dataclasses import dataclass
from functools import cache
from pathlib import Path

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


@dataclass(frozen=True, eq=False)
class SerialLine:
    """A serial line: equal to another where both open one device, whatever the paths.

    ``path``: the device file named, links followed; ``device``: its major and
    minor numbers where it is a character device now, else None (then the
    path is what is compared).
    """

    path: str
    device: tuple[int, int] | None

    @classmethod
    def at(cls, path: str) -> SerialLine:
        real = os.path.realpath(path)
        try:
            info = os.stat(real)
        except OSError:  # not there now (an adapter unplugged): the path is all there is
            return cls(real, None)
        if not stat.S_ISCHR(info.st_mode):
            return cls(real, None)
        return cls(real, (os.major(info.st_rdev), os.minor(info.st_rdev)))

    @property
    def key(self) -> tuple[str | int, ...]:
        return ("path", self.path) if self.device is None else ("device", *self.device)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, SerialLine) and self.key == other.key

    def __hash__(self) -> int:
        return hash(self.key)

    def __str__(self) -> str:
        if self.device is None:
            return self.path
        return f"{self.path} (device {self.device[0]}:{self.device[1]})"


def serial_endpoint(path: str) -> Endpoint:
    """A serial line, by the device it opens (:class:`SerialLine`)."""
    return ("serial", SerialLine.at(path))


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
    """One spelling per host: this machine's (:data:`LOOPBACK`), an IP address in canonical form, or the name."""
    name = host.strip().lower().rstrip(".")
    if name.startswith("[") and name.endswith("]"):
        name = name[1:-1]
    literal = _ip_key(name)
    if literal is not None:
        return literal
    if name in _LOCAL_NAMES or name.endswith(".localhost") or name == _own_name():
        return LOOPBACK
    addresses = {key for key in map(_ip_key, _resolve(name)) if key is not None}
    if LOOPBACK in addresses:  # a name for this machine, whatever else it resolves to
        return LOOPBACK
    return min(addresses) if addresses else name


def _ip_key(text: str) -> str | None:
    """An IP address's key (this machine's: :data:`LOOPBACK`), or None for a name."""
    try:
        ip = ipaddress.ip_address(text.partition("%")[0])
    except ValueError:
        return None
    if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:
        ip = ip.ipv4_mapped
    if ip.is_loopback or ip.is_unspecified or ip.compressed in local_addresses():
        return LOOPBACK
    return ip.compressed


@cache
def _own_name() -> str:
    return socket.gethostname().lower().rstrip(".")


@cache
def local_addresses() -> frozenset[str]:
    """The IP addresses of this machine's interfaces (canonical spelling), once per process.

    Linux lists them in ``/proc/net/fib_trie`` (IPv4: each ``/32 host LOCAL``
    entry, secondary addresses included) and ``/proc/net/if_inet6``, for the
    network namespace compd runs in; the addresses the host name resolves to
    are added (and are all there is elsewhere). The standard library has no
    call for them, and compd takes no dependency for this one check.
    """
    found: set[str] = set()
    try:
        last = ""
        for line in Path("/proc/net/fib_trie").read_text().splitlines():
            text = line.strip()
            if text.startswith("|-- "):
                last = text[4:]
            elif text == "/32 host LOCAL" and last:
                found.add(last)
    except OSError:
        pass
    try:
        for line in Path("/proc/net/if_inet6").read_text().splitlines():
            digits = line.split()[0]
            found.add(":".join(digits[i : i + 4] for i in range(0, 32, 4)))
    except (OSError, IndexError):
        pass
    found.update(_resolve(_own_name()))
    keys = set()
    for text in found:
        try:
            ip = ipaddress.ip_address(text.partition("%")[0])
        except ValueError:
            continue
        keys.add(ip.compressed)
    return frozenset(keys)


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
