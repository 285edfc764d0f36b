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
is answered (if it can be) and logged, and the server goes on serving. No
peer can lock the operators out: at most 16 clients are connected at once
(fewer where the open-files limit is low, :mod:`compd.service.control.peers`), one
user who may not load models holds at most 4 of them, 4 are kept for the
users who may, and a client that has not sent a whole request within 10 s
is dropped. A client turned away is told why (``busy: ...``), and the
episode is logged once. A socket file
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
from collections.abc import Awaitable, Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from compd.errors import CompdError, ControlError, NotRunningError
from compd.faultlog import FaultLog
from compd.service.config.admission import Access, Admission, Peer, peer_of

if TYPE_CHECKING:  # the server's only: `compd status` imports the client, and no structlog
    from compd.service.control.peers import FdBudget, Listener

log = logging.getLogger(__name__)

DEFAULT_SOCKET_PATH = Path("/run/compd/control.sock")
"""Where ``compd run`` listens under the systemd unit (``RuntimeDirectory=compd``)."""

SOCKET_MODE = 0o660
MAX_LINE_BYTES = 2 << 20  # a command and a few options; at most a model file (1 MiB, base64)
MAX_CONNECTIONS = 16  # a few operators and scripts; more is a runaway client
MAX_PER_PEER = 4  # connections one user who may not load models holds at once
RESERVED_FOR_ACCESS = 4  # connections only users allowed a guarded command (load) may take
IDLE_TIMEOUT_S = 10.0  # a client that sends no whole request this long is disconnected
BACKLOG = 64  # clients the kernel queues while the server is judging others
#: Why JSON nested deeper than Python's parser can follow (a RecursionError) is refused.
TOO_DEEP = "arrays or objects nested too deeply to parse (a request is one flat JSON object)"

Handler = Callable[[dict[str, Any]], Awaitable[dict[str, Any]]]
"""A command: takes the request object, returns the reply's fields (``ok`` is added)."""


class ControlServer:
    """Serve ``handlers`` on the unix socket ``path``.

    ``handlers`` maps a command name to an async function that takes the
    whole request (``cmd`` included) and returns the reply's fields. A
    handler raising :class:`~compd.errors.CompdError` is a refusal (its
    message is the reply's ``error``); any other exception is a bug, logged
    with its traceback and answered as ``internal error``. A command named in
    ``access`` runs only for the peers its :class:`Access` allows.

    Of the ``max_connections``, a peer no :class:`Access` allows (a
    status-only user) may hold ``max_per_peer``, and such peers together all
    but ``reserved`` of them: those are kept for the allowed peers. ``budget``
    may lower ``max_connections`` to what the open-files limit leaves.
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
        max_per_peer: int = MAX_PER_PEER,
        reserved: int = RESERVED_FOR_ACCESS,
        budget: FdBudget | None = None,
    ) -> None:
        self.path = Path(path)
        self.handlers = dict(handlers)
        self.access = dict(access or {})
        self.mode = mode
        #: Who is served, turned away, kept room for (:mod:`compd.service.config.admission`).
        self.admission = Admission(max_connections, max_per_peer, reserved, self.access)
        self.idle_timeout_s = idle_timeout_s
        self.budget = budget
        self._listener: Listener | None = None
        self._inode: tuple[int, int] | None = None
        #: The connections being served, and the peer of each.
        self._connections: dict[asyncio.Task[None], Peer | None] = {}
        self._busy = FaultLog(_structlog(), level="warning")

    async def start(self) -> None:
        """Bind the socket (replacing a stale one), set its mode, and accept connections.

        Raises :class:`~compd.errors.ControlError` when another process
        listens on ``path``, when ``path`` is not a socket, or when it cannot
        be bound.
        """
        if self._listener is not None:
            return
        await _remove_stale(self.path)
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            sock.bind(os.fspath(self.path))
            # Before listen(): nobody can connect while the mode is still the umask's.
            os.chmod(self.path, self.mode)
            info = os.stat(self.path)
            sock.listen(BACKLOG)
        except OSError as exc:
            sock.close()
            raise ControlError(f"cannot listen on {self.path}: {exc.strerror or exc}") from exc
        self._inode = (info.st_dev, info.st_ino)
        from compd.service.control.peers import FdBudget, Listener

        # One slot beyond the most served: a client over the limit is accepted, told
        # "busy" and closed at once, instead of waiting unanswered in the queue.
        admission = self.admission
        cap = (self.budget or FdBudget()).take(admission.max_connections + 1, "control socket")
        admission.max_connections = max(1, cap - 1)
        self._listener = Listener(sock, admission.max_connections + 1, self._admit, name="control")
        self._listener.start()
        log.info("control socket listening on %s", self.path)

    async def close(self) -> None:
        """Stop accepting, end open connections and remove the socket file (if still ours)."""
        listener, self._listener = self._listener, None
        if listener is None:
            return
        await listener.close()
        for task in list(self._connections):
            task.cancel()
        await asyncio.gather(*self._connections, return_exceptions=True)
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

    def _admit(self, conn: socket.socket, release: Callable[[], None]) -> None:
        """Serve the accepted ``conn`` (the :class:`Listener`'s), or tell it why not and close it."""
        peer = peer_of(conn)
        refusal = self.admission.turned_away(peer, self._connections.values())
        if refusal is None:
            task = asyncio.get_running_loop().create_task(self._serve(conn, peer, release))
            self._connections[task] = peer
            return
        self._busy.failed("control socket busy: clients turned away", reason=refusal)
        with contextlib.suppress(OSError):  # a few bytes: the socket's buffer takes them
            conn.send(_encode(_refusal(refusal)))
        conn.close()
        release()

    async def _serve(
        self, conn: socket.socket, peer: Peer | None, release: Callable[[], None]
    ) -> None:
        task = asyncio.current_task()
        assert task is not None
        writer: asyncio.StreamWriter | None = None
        try:
            reader, writer = await asyncio.open_unix_connection(sock=conn, limit=MAX_LINE_BYTES)
            while True:
                try:
                    # The whole line within the timeout: a client sending it slowly is cut too.
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
            # The slot first: a client that sees the end of the stream finds it free.
            self._connections.pop(task, None)
            release()
            if not self._connections:
                self._busy.cleared("control socket serving every client again")
            if writer is None:
                conn.close()
            else:
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
    loop = asyncio.get_running_loop()
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    sock.setblocking(False)
    try:
        async with asyncio.timeout(timeout_s):
            try:
                await loop.sock_connect(sock, os.fspath(path))
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
            # A busy server answers and closes before it reads the request: the write
            # may fail, and the answer is still there to read (plain sockets keep it).
            with contextlib.suppress(BrokenPipeError, ConnectionResetError):
                await loop.sock_sendall(sock, _encode(message))
            line = await _read_line(loop, sock, path)
    except TimeoutError:
        raise ControlError(f"no reply from compd on {path} within {timeout_s:g} s") from None
    except OSError as exc:
        raise ControlError(f"cannot talk to compd on {path}: {exc.strerror or exc}") from exc
    finally:
        sock.close()
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


async def _read_line(loop: asyncio.AbstractEventLoop, sock: socket.socket, path: Path) -> bytes:
    """One reply line (empty if the server closed first), at most :data:`MAX_LINE_BYTES`."""
    data = bytearray()
    while b"\n" not in data:
        chunk = await loop.sock_recv(sock, 1 << 16)
        if not chunk:
            return bytes(data)
        data += chunk
        if len(data) > MAX_LINE_BYTES:
            raise ControlError(f"compd sent a reply longer than {MAX_LINE_BYTES} bytes on {path}")
    return bytes(data[: data.index(b"\n") + 1])


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


def _structlog() -> Any:
    import structlog  # the server's: the command line's client needs none

    return structlog.get_logger(__name__)


def _refusal(error: str) -> dict[str, Any]:
    return {"ok": False, "error": error}
