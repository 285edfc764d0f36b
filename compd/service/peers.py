"""Connections from peers, bounded: no client can take the file descriptors the machine needs.

Every connection the daemon accepts costs a file descriptor, and the process
has a fixed number of them (``RLIMIT_NOFILE``: 1024 by default under
systemd, ``LimitNOFILE=`` in the units). If the HTTP server or the control
socket accepted whatever arrives, 1,000 slow clients would leave none for
what the compensation needs: a PLC link reconnecting, the state file, a new
recording. So each listening socket is served by a :class:`Listener` that
accepts at most its cap of connections at once; further clients wait in the
kernel's accept queue (they cost the daemon nothing there) until a slot
frees, and a slow client is cut by its server's own idle timeout.

The caps come from one :class:`FdBudget` per process: the open-files limit,
less the descriptors already open, less :data:`RESERVED_FDS` kept for the
machine's own links and files. A cap the budget cannot honour is lowered,
with a warning naming ``LimitNOFILE``.

A listener at its cap logs one WARNING when the episode starts and one INFO
when it has caught up (nobody waiting), never a line per client; running out
of descriptors anyway (another part of the process used them) is an ERROR
once per episode, and accepting resumes after a short pause.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import os
import resource
import socket
import struct
from collections.abc import Callable

import structlog

from compd.faultlog import FaultLog

log = structlog.get_logger("compd.service.peers")

#: Descriptors kept free of every listener's connections: the PLC links and their
#: reconnects, the state file and its directory, the recorder's files, telemetry,
#: the log and the model checks (each needs a few; 64 leaves a wide margin).
RESERVED_FDS = 64
#: Pause before accepting again after the process ran out of descriptors (s).
ACCEPT_RETRY_S = 0.5
#: accept() errors that mean "no descriptor or memory now", not a bad listener.
STARVED = frozenset({errno.EMFILE, errno.ENFILE, errno.ENOBUFS, errno.ENOMEM})
#: accept() errors of one client that went away while queued.
GONE = frozenset({errno.ECONNABORTED, errno.EPROTO, errno.EPERM})

#: Called with each accepted connection (non-blocking); it must call ``release`` once
#: when the connection is closed, however it ends.
Admit = Callable[[socket.socket, Callable[[], None]], None]


def fds_in_use() -> int:
    """The descriptors this process has open now (``/proc/self/fd``; 0 where there is none)."""
    try:
        return len(os.listdir("/proc/self/fd")) - 1  # less the one listdir held
    except OSError:
        return 0


class FdBudget:
    """The descriptors the listeners of one process may spend on connections, shared out by :meth:`take`."""

    def __init__(self, *, reserve: int = RESERVED_FDS) -> None:
        self.limit = resource.getrlimit(resource.RLIMIT_NOFILE)[0]
        self.reserve = reserve
        unlimited = self.limit == resource.RLIM_INFINITY
        self.free = 1 << 20 if unlimited else self.limit - fds_in_use() - reserve

    def take(self, wanted: int, what: str) -> int:
        """Up to ``wanted`` connections for ``what``: at least 1, less where the limit is too low."""
        granted = max(1, min(wanted, self.free))
        self.free -= granted
        if granted < wanted:
            log.warning(
                "the open-files limit leaves too few descriptors for the connections wanted; "
                "raise LimitNOFILE= in the unit (or ulimit -n)",
                listener=what,
                connections=granted,
                wanted=wanted,
                limit=self.limit,
                reserved=self.reserve,
            )
        return granted


class Listener:
    """Accept connections on the listening ``sock``, at most ``cap`` of them open at once.

    Each accepted connection goes to ``admit`` with the function that gives
    its slot back. :meth:`start` begins accepting, :meth:`close` stops and
    closes ``sock`` (the connections are their server's to close).
    """

    def __init__(self, sock: socket.socket, cap: int, admit: Admit, *, name: str) -> None:
        self.sock = sock
        self.cap = cap
        self.admit = admit
        self.name = name
        #: Connections accepted and not yet released.
        self.open = 0
        self._room = asyncio.Event()
        self._full = FaultLog(log, level="warning", listener=name)
        self._starved = FaultLog(log, listener=name)
        self._task: asyncio.Task[None] | None = None
        sock.setblocking(False)

    def start(self) -> None:
        self._task = asyncio.get_running_loop().create_task(self._accept_loop())

    async def close(self) -> None:
        task, self._task = self._task, None
        if task is not None:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
        self.sock.close()

    def slot(self) -> Callable[[], None]:
        """Take a slot; the function returned gives it back (once, however often it is called)."""
        self.open += 1
        given_back = False

        def release() -> None:
            nonlocal given_back
            if not given_back:
                given_back = True
                self.open -= 1
                self._room.set()

        return release

    async def _accept_loop(self) -> None:
        loop = asyncio.get_running_loop()
        while True:
            if self.open >= self.cap:
                self._full.failed(
                    "too many connections: further clients wait until one closes",
                    connections=self.open,
                )
                self._room.clear()
                await self._room.wait()
                continue
            try:
                try:
                    conn, _ = self.sock.accept()
                except BlockingIOError:
                    # Nobody waiting and half the slots free: the episode is over (not
                    # at every slot freed, which an attacker refilling would repeat).
                    if self.open <= self.cap // 2:
                        self._full.cleared("connections below the cap again", connections=self.open)
                    conn, _ = await loop.sock_accept(self.sock)
            except OSError as exc:
                if exc.errno in GONE:
                    continue
                # Out of descriptors (or a listener fault): once per episode, no traceback.
                self._starved.failed("cannot accept a connection", error=str(exc))
                await asyncio.sleep(ACCEPT_RETRY_S)
                continue
            self._starved.cleared("accepting connections again")
            conn.setblocking(False)
            release = self.slot()
            try:
                self.admit(conn, release)
            except Exception:  # a server bug must not stop the accepting
                log.exception("cannot serve a connection", listener=self.name)
                conn.close()
                release()


class Counted(asyncio.Protocol):
    """``inner``, a connection's protocol, that gives its slot back when the connection is lost.

    It also cuts a client that stops reading: answers wait for a client whose
    buffers are full (flow control pauses the writer), and one that keeps
    them full for ``stall_timeout_s`` is aborted instead of holding its slot.
    """

    def __init__(
        self, inner: asyncio.Protocol, release: Callable[[], None], stall_timeout_s: float
    ) -> None:
        self.inner = inner
        self.release = release
        self.stall_timeout_s = stall_timeout_s
        self._transport: asyncio.BaseTransport | None = None
        self._stalled: asyncio.TimerHandle | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self._transport = transport
        self.inner.connection_made(transport)

    def data_received(self, data: bytes) -> None:
        self.inner.data_received(data)

    def eof_received(self) -> bool | None:
        return self.inner.eof_received()

    def pause_writing(self) -> None:
        if self._transport is not None and self._stalled is None:
            loop = asyncio.get_running_loop()
            self._stalled = loop.call_later(self.stall_timeout_s, self._cut)
        self.inner.pause_writing()

    def _cut(self) -> None:
        """Abort a stalled connection with a reset: the kernel drops what it still holds for it."""
        transport = self._transport
        assert transport is not None
        sock = transport.get_extra_info("socket")
        if sock is not None:
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        getattr(transport, "abort", transport.close)()

    def resume_writing(self) -> None:
        if self._stalled is not None:
            self._stalled.cancel()
            self._stalled = None
        self.inner.resume_writing()

    def connection_lost(self, exc: Exception | None) -> None:
        if self._stalled is not None:
            self._stalled.cancel()
        try:
            self.inner.connection_lost(exc)
        finally:
            self.release()


def serve_protocol(factory: Callable[[], asyncio.Protocol], *, stall_timeout_s: float) -> Admit:
    """An :data:`Admit` that serves each connection with a new ``factory()`` protocol.

    ``stall_timeout_s``: the longest a client may leave an answer unread (:class:`Counted`).
    """

    def admit(conn: socket.socket, release: Callable[[], None]) -> None:
        loop = asyncio.get_running_loop()
        protocol = Counted(factory(), release, stall_timeout_s)
        task = loop.create_task(loop.connect_accepted_socket(lambda: protocol, conn))

        def settled(task: asyncio.Task[object]) -> None:
            if task.cancelled() or task.exception() is not None:
                conn.close()
                release()

        task.add_done_callback(settled)

    return admit
