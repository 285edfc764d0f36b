"""The control socket: how ``compd status`` and ``compd model load`` talk to a running daemon.

A unix stream socket (``/run/compd/control.sock`` under systemd, in the
unit's ``RuntimeDirectory``) speaking JSON lines: the client sends one object
``{"cmd": "status", ...}`` per line and gets one object per line back,
``{"ok": true, ...}`` or ``{"ok": false, "error": "..."}``. Local only, so
access is file permission: the socket is ``0660``, usable by the daemon's
user and group, and nobody on the network can move a machine's offsets.
Within that group, a command may need more: the kernel tells the server who
connected (``SO_PEERCRED``: pid, uid, gid), and a command given an
:class:`Access` (``load``, which moves the offsets) is refused to any other
peer, while ``status`` stays open to the whole group.

The server must never be the reason the compensation loop stops: a malformed
line, an unknown command, a handler that raises or a client that vanishes
is answered (if it can be) and logged, and the server goes on serving; at
most 16 clients are connected at once, each dropped after 5 minutes of
silence, so a runaway script cannot lock the operators out. A socket file
left by a crashed daemon is replaced; a socket with a live daemon behind it
is refused, so a second ``compd run`` cannot hijack the first one's controls.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import math
import os
import socket
import stat
import struct
from collections.abc import Awaitable, Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from compd.errors import CompdError, ControlError, NotRunningError

log = logging.getLogger(__name__)

DEFAULT_SOCKET_PATH = Path("/run/compd/control.sock")
"""Where ``compd run`` listens under the systemd unit (``RuntimeDirectory=compd``)."""

SOCKET_MODE = 0o660
MAX_LINE_BYTES = 2 << 20  # a command and a few options; at most a model file (1 MiB, base64)
MAX_CONNECTIONS = 16  # a few operators and scripts; more is a runaway client
IDLE_TIMEOUT_S = 300.0  # a client silent this long is disconnected, so it cannot hold a slot
#: Why JSON nested deeper than Python's parser can follow (a RecursionError) is refused.
TOO_DEEP = "arrays or objects nested too deeply to parse (a request is one flat JSON object)"

Handler = Callable[[dict[str, Any]], Awaitable[dict[str, Any]]]
"""A command: takes the request object, returns the reply's fields (``ok`` is added)."""


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


def peer_of(writer: asyncio.StreamWriter) -> Peer | None:
    """The connected process's credentials (``SO_PEERCRED``), or None where the OS has none."""
    sock = writer.get_extra_info("socket")
    option = getattr(socket, "SO_PEERCRED", None)
    if sock is None or option is None:
        return None
    try:
        raw = sock.getsockopt(socket.SOL_SOCKET, option, struct.calcsize("3i"))
    except OSError:
        return None
    return Peer(*struct.unpack("3i", raw))


class ControlServer:
    """Serve ``handlers`` on the unix socket ``path``.

    ``handlers`` maps a command name to an async function that takes the
    whole request (``cmd`` included) and returns the reply's fields. A
    handler raising :class:`~compd.errors.CompdError` is a refusal (its
    message is the reply's ``error``); any other exception is a bug, logged
    with its traceback and answered as ``internal error``. A command named in
    ``access`` runs only for the peers its :class:`Access` allows.
    """

    def __init__(
        self,
        path: Path,
        handlers: Mapping[str, Handler],
        *,
        mode: int = SOCKET_MODE,
        max_connections: int = MAX_CONNECTIONS,
        idle_timeout_s: float = IDLE_TIMEOUT_S,
        access: Mapping[str, Access] | None = None,
    ) -> None:
        self.path = Path(path)
        self.handlers = dict(handlers)
        self.access = dict(access or {})
        self.mode = mode
        self.max_connections = max_connections
        self.idle_timeout_s = idle_timeout_s
        self._server: asyncio.Server | None = None
        self._inode: tuple[int, int] | None = None
        self._connections: set[asyncio.Task[None]] = set()

    async def start(self) -> None:
        """Bind the socket (replacing a stale one), set its mode, and accept connections.

        Raises :class:`~compd.errors.ControlError` when another process
        listens on ``path``, when ``path`` is not a socket, or when it cannot
        be bound.
        """
        if self._server is not None:
            return
        await _remove_stale(self.path)
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            sock.bind(os.fspath(self.path))
            # Before listen(): nobody can connect while the mode is still the umask's.
            os.chmod(self.path, self.mode)
            info = os.stat(self.path)
            self._server = await asyncio.start_unix_server(
                self._serve, sock=sock, limit=MAX_LINE_BYTES
            )
        except OSError as exc:
            sock.close()
            raise ControlError(f"cannot listen on {self.path}: {exc.strerror or exc}") from exc
        self._inode = (info.st_dev, info.st_ino)
        log.info("control socket listening on %s", self.path)

    async def close(self) -> None:
        """Stop accepting, end open connections and remove the socket file (if still ours)."""
        server, self._server = self._server, None
        if server is None:
            return
        server.close()
        for task in list(self._connections):
            task.cancel()
        await asyncio.gather(*self._connections, return_exceptions=True)
        await server.wait_closed()
        with contextlib.suppress(OSError):
            info = os.stat(self.path)
            if (info.st_dev, info.st_ino) == self._inode:  # a newer daemon's socket stays
                os.unlink(self.path)
        self._inode = None

    async def __aenter__(self) -> ControlServer:
        await self.start()
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.close()

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._connections.add(task)
        peer = peer_of(writer)
        try:
            if len(self._connections) > self.max_connections:
                await _send(writer, _refusal(f"busy: {self.max_connections} clients connected"))
                return
            while True:
                try:
                    async with asyncio.timeout(self.idle_timeout_s):
                        line = await reader.readline()
                except (ValueError, asyncio.LimitOverrunError):
                    await _send(writer, _refusal(f"request longer than {MAX_LINE_BYTES} bytes"))
                    return  # the rest of the stream cannot be framed again
                except TimeoutError:
                    return  # idle: free the slot for someone else
                if not line:
                    return
                if line.strip():
                    await _send(writer, await self.answer(line, peer))
        except (ConnectionError, asyncio.CancelledError):
            pass  # the client went away, or the server is closing
        finally:
            self._connections.discard(task)
            writer.close()
            with contextlib.suppress(Exception):
                await writer.wait_closed()

    async def answer(self, line: bytes, peer: Peer | None = None) -> dict[str, Any]:
        """The reply to one request line from ``peer``; never raises."""
        try:
            request = json.loads(line)
        except (ValueError, UnicodeDecodeError) as exc:
            return _refusal(f"malformed JSON request: {exc}")
        except RecursionError:  # json's parser recurses per [ or {: a line of 2 MiB "[" ends here
            return _refusal(f"malformed JSON request: {TOO_DEEP}")
        if not isinstance(request, dict):
            return _refusal('a request is a JSON object such as {"cmd": "status"}')
        command = request.get("cmd")
        handler = self.handlers.get(command) if isinstance(command, str) else None
        if handler is None:
            known = ", ".join(sorted(self.handlers))
            return _refusal(f"unknown command {command!r}; known commands: {known}")
        access = self.access.get(str(command))
        if access is not None and not access.allows(peer):
            log.warning("control command %r refused to %s", command, peer)
            who = "an unknown peer" if peer is None else f"uid {peer.uid}, gid {peer.gid}"
            return _refusal(
                f"permission denied: {command!r} is allowed for uids {sorted(access.uids)} and "
                f"gids {sorted(access.gids)}, not {who}; run it as the service's user (see the "
                "config's 'load_access')"
            )
        try:
            result = await handler(request)
        except CompdError as exc:
            return _refusal(str(exc))
        except Exception as exc:  # a handler bug must not take the control socket down
            log.exception("control command %r failed", command)
            # The exception's text is cut: it may quote what the request carried.
            return _refusal(
                f"internal error in {command!r}: {type(exc).__name__}: {str(exc)[:200]}"
            )
        if not isinstance(result, dict):
            log.error("control command %r returned %r, not a dict", command, type(result))
            return _refusal(f"internal error in {command!r}: the reply is not an object")
        return {"ok": True, **result}


async def request(path: Path, message: dict[str, Any], *, timeout_s: float = 5.0) -> dict[str, Any]:
    """Send one request to the daemon at ``path`` and return its reply (``ok`` may be false).

    Raises :class:`~compd.errors.ControlError` when no daemon listens, when
    access is denied, and when no reply comes within ``timeout_s``.
    """
    path = Path(path)
    try:
        async with asyncio.timeout(timeout_s):
            try:
                reader, writer = await asyncio.open_unix_connection(
                    os.fspath(path), limit=MAX_LINE_BYTES
                )
            except FileNotFoundError:
                # How to start it depends on the install: the command line adds the hint.
                raise NotRunningError(f"is compd running? socket {path} not found") from None
            except ConnectionRefusedError:
                raise NotRunningError(
                    f"is compd running? nothing listens on {path} (a stale socket)"
                ) from None
            except PermissionError:
                raise ControlError(
                    f"permission denied on {path}: run as root or as a member of the socket's group"
                ) from None
            try:
                writer.write(_encode(message))
                await writer.drain()
                line = await reader.readline()
            finally:
                writer.close()
    except TimeoutError:
        raise ControlError(f"no reply from compd on {path} within {timeout_s:g} s") from None
    except OSError as exc:
        raise ControlError(f"cannot talk to compd on {path}: {exc.strerror or exc}") from exc
    if not line:
        raise ControlError(f"compd closed the connection on {path} without a reply")
    try:
        reply = json.loads(line)
    except (ValueError, RecursionError) as exc:
        what = TOO_DEEP if isinstance(exc, RecursionError) else exc
        raise ControlError(f"compd sent a malformed reply on {path}: {what}") from exc
    if not isinstance(reply, dict):
        raise ControlError(f"compd sent a reply that is not an object on {path}: {reply!r}")
    return reply


def request_sync(path: Path, message: dict[str, Any], *, timeout_s: float = 5.0) -> dict[str, Any]:
    """:func:`request` for code that has no event loop (the command line)."""
    return asyncio.run(request(path, message, timeout_s=timeout_s))


async def _remove_stale(path: Path) -> None:
    """Remove a socket file nobody listens on; refuse a live socket or a non-socket file."""
    try:
        info = os.stat(path)
    except FileNotFoundError:
        return
    if not stat.S_ISSOCK(info.st_mode):
        raise ControlError(
            f"{path} exists and is not a socket; remove it or choose another control socket path"
        )
    try:
        _, writer = await asyncio.wait_for(asyncio.open_unix_connection(os.fspath(path)), 1.0)
    except (ConnectionRefusedError, FileNotFoundError):
        log.info("replacing the stale control socket %s", path)
        with contextlib.suppress(FileNotFoundError):
            os.unlink(path)
        return
    except (OSError, TimeoutError) as exc:
        raise ControlError(f"cannot check the control socket {path}: {exc}") from exc
    writer.close()
    raise ControlError(f"another compd is already listening on {path}; stop it first")


def _encode(message: dict[str, Any]) -> bytes:
    return (json.dumps(jsonable(message), allow_nan=False) + "\n").encode()


def jsonable(value: Any) -> Any:
    """``value`` in JSON's types: NaN and infinities become null (JSON has neither), numpy
    scalars Python numbers, paths strings; anything else raises TypeError."""
    if isinstance(value, dict):
        return {str(key): jsonable(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [jsonable(item) for item in value]
    if isinstance(value, str | bool | int) or value is None:
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    item = getattr(value, "item", None)  # numpy scalars
    if callable(item):
        return jsonable(item())
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")


async def _send(writer: asyncio.StreamWriter, reply: dict[str, Any]) -> None:
    try:
        data = _encode(reply)
    except (TypeError, ValueError) as exc:  # NaN, or an object JSON has no form for
        log.error("control reply %r cannot be sent as JSON: %s", reply, exc)
        data = _encode(_refusal(f"internal error: the reply cannot be sent as JSON ({exc})"))
    writer.write(data)
    await writer.drain()


def _refusal(error: str) -> dict[str, Any]:
    return {"ok": False, "error": error}
