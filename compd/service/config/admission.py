"""Who is at the other end of the control socket, what they may run, and whether they are served at all.

The kernel tells a unix socket's server who connected (``SO_PEERCRED``:
pid, uid, gid): a :class:`Peer`. A command given an :class:`Access`
(``load``, which moves the offsets) runs only for the peers it allows.
:class:`Admission` decides at connect time whether a peer is served, so
that no peer can hold the slots of those who may load: a peer no Access
allows (a status-only member of the socket's group) holds at most
``max_per_peer`` connections, such peers together all but ``reserved``,
which are kept for the allowed ones.
"""

from __future__ import annotations

import socket
import struct
from collections.abc import Collection, Mapping
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Peer:
    """The process at the other end of a connection, as the kernel saw it connect."""

    pid: int
    uid: int
    gid: int


@dataclass(frozen=True)
class Access:
    """Who may run a command: a peer whose uid is in ``uids`` or whose (primary) gid is in ``gids``."""

    uids: frozenset[int]
    gids: frozenset[int] = frozenset()

    def allows(self, peer: Peer | None) -> bool:
        return peer is not None and (peer.uid in self.uids or peer.gid in self.gids)


def peer_of(sock: Any) -> Peer | None:
    """The credentials of the process connected on the unix socket ``sock``, or None where the OS has none."""
    option = getattr(socket, "SO_PEERCRED", None)
    if sock is None or option is None:
        return None
    try:
        raw = sock.getsockopt(socket.SOL_SOCKET, option, struct.calcsize("3i"))
    except OSError:
        return None
    return Peer(*struct.unpack("3i", raw))


@dataclass
class Admission:
    """Whether a new connection is served, given the peers connected: :meth:`turned_away`.

    ``access``: the guarded commands; a peer one of them allows is
    privileged. With no guarded command nothing is kept back.
    """

    max_connections: int
    max_per_peer: int
    reserved: int
    access: Mapping[str, Access]

    def privileged(self, peer: Peer | None) -> bool:
        """Whether ``peer`` may run a guarded command."""
        return any(access.allows(peer) for access in self.access.values())

    def turned_away(self, peer: Peer | None, connected: Collection[Peer | None]) -> str | None:
        """Why a new connection from ``peer`` is refused (a ``busy: ...`` answer), or None if served."""
        if len(connected) >= self.max_connections:
            return f"busy: {self.max_connections} clients connected"
        if self.privileged(peer):
            return None
        others = [p for p in connected if not self.privileged(p)]
        kept = min(self.reserved, self.max_connections - 1) if self.access else 0
        if len(others) >= self.max_connections - kept:
            commands = ", ".join(sorted(self.access))
            return (
                f"busy: {len(others)} clients connected; the other {kept} connections are "
                f"kept for the users who may run {commands}"
            )
        uid = None if peer is None else peer.uid
        mine = sum(1 for p in others if (None if p is None else p.uid) == uid)
        if mine >= self.max_per_peer:
            who = "this user" if uid is None else f"uid {uid}"
            return (
                f"busy: {who} already has {mine} connections, the most one user may hold; "
                "close one first"
            )
        return None
