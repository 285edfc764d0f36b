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

That queue is first come, first served, so a flood of clients that connect
and send nothing (or half a request) would hold a scraper behind it for the
idle timeout times the queue over the cap. A listener given ``evict``
(the HTTP server's, :class:`Served`) therefore never waits behind idle
connections: when every slot is taken it closes the connection that has
been idle longest (no request under way, nothing left to send, nothing
received for :data:`EVICT_IDLE_S`) and accepts the next client in its
place, so the queue drains at the rate of accepting, and a client that
sends its request gets it answered however many idle ones there are.

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
import math
import os
import resource
import socket
import struct
from collections.abc import Callable, Iterator

import structlog

from compd.faultlog import FaultLog

log = structlog.get_logger("compd.service.control.peers")

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
#: A connection idle this long (s: no request under way, nothing received) may be closed
#: for a new client when every slot is taken. What keeps a client just accepted until its
#: request is read (it usually arrives with the handshake's last packet, a loop iteration
#: or two later) is the order: the idlest goes first, and one client is accepted per
#: eviction, so a newcomer outlives the cap's worth of clients accepted after it. This
#: is a floor under that on a stalled loop, short, so the slots turn over fast enough
#: (at most cap / this, 12,800 a second at 64) to drain a queue of a thousand in well
#: under a second.
EVICT_IDLE_S = 0.005
#: The longest a listener waits, none being idle (each answering a request), before it
#: looks again (s).
EVICT_WAIT_S = 0.05

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

    ``evict``, where given, is asked to close an idle connection whenever
    every slot is taken (:meth:`Served.evict_idlest`): it returns 0 if it
    did, else the seconds until one may be closed (``inf``: none is idle).
    Without it, further clients wait until a connection ends.
    """

    def __init__(
        self,
        sock: socket.socket,
        cap: int,
        admit: Admit,
        *,
        name: str,
        evict: Callable[[], float] | None = None,
    ) -> None:
        self.sock = sock
        self.cap = cap
        self.admit = admit
        self.name = name
        self.evict = evict
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

    async def _room_within(self, timeout_s: float) -> None:
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(timeout_s):
                await self._room.wait()

    async def _accept_loop(self) -> None:
        loop = asyncio.get_running_loop()
        while True:
            if self.open >= self.cap:
                self._room.clear()
                if self.evict is None:
                    self._full.failed(
                        "too many connections: further clients wait until one closes",
                        connections=self.open,
                    )
                    await self._room.wait()
                    continue
                if not self._full.active:  # not even a DEBUG line per client: thousands a second
                    self._full.failed(
                        "too many connections: the longest idle are closed for new clients",
                        connections=self.open,
                    )
                wait_s = self.evict()
                if wait_s == 0:
                    # Idle, it had nothing to send: its connection_lost, and the slot, come
                    # in the next loop iteration.
                    await self._room.wait()
                else:  # look again once the idlest may go
                    await self._room_within(min(wait_s, EVICT_WAIT_S))
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
    And it knows whether the connection is idle, for :meth:`Served.evict_idlest`.
    """

    def __init__(
        self,
        inner: asyncio.Protocol,
        release: Callable[[], None],
        stall_timeout_s: float,
        live: dict[asyncio.BaseTransport, Counted] | None = None,
    ) -> None:
        self.inner = inner
        self.release = release
        self.stall_timeout_s = stall_timeout_s
        #: Requests under way (:meth:`Served.busy`): a connection with one is never evicted.
        self.requests = 0
        #: When it last received data or finished an answer (``loop.time()`` s).
        self.active_s = asyncio.get_running_loop().time()
        self._live = live
        self._transport: asyncio.BaseTransport | None = None
        self._stalled: asyncio.TimerHandle | None = None

    @property
    def idle(self) -> bool:
        """No request under way, nothing left to send, not closing: closing it loses nothing."""
        transport = self._transport
        if transport is None or transport.is_closing() or self.requests:
            return False
        return not isinstance(transport, asyncio.WriteTransport) or not (
            transport.get_write_buffer_size()
        )

    def evict(self) -> None:
        """Close the connection (idle: it has nothing to send, the close is at once)."""
        if self._transport is not None:
            self._transport.close()

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self._transport = transport
        if self._live is not None:
            self._live[transport] = self
        self.inner.connection_made(transport)

    def touch(self) -> None:
        """It is active now: the last of the live connections in the order of idleness."""
        self.active_s = asyncio.get_running_loop().time()
        if self._live is not None and self._transport is not None:
            self._live.pop(self._transport, None)
            self._live[self._transport] = self

    def data_received(self, data: bytes) -> None:
        self.touch()
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
        if self._live is not None and self._transport is not None:
            self._live.pop(self._transport, None)
        try:
            self.inner.connection_lost(exc)
        finally:
            self.release()


class Served:
    """An :data:`Admit` that serves each connection with a new ``factory()`` protocol, and frees slots.

    ``stall_timeout_s``: the longest a client may leave an answer unread
    (:class:`Counted`). The server marks each request under way with
    :meth:`busy`; :meth:`evict_idlest` is the :class:`Listener`'s ``evict``.
    """

    def __init__(
        self,
        factory: Callable[[], asyncio.Protocol],
        *,
        stall_timeout_s: float,
        evict_idle_s: float = EVICT_IDLE_S,
    ) -> None:
        self.factory = factory
        self.stall_timeout_s = stall_timeout_s
        self.evict_idle_s = evict_idle_s
        #: The connections being served, by transport, idlest first (:meth:`Counted.touch`).
        self.live: dict[asyncio.BaseTransport, Counted] = {}
        #: Connections closed to make room so far.
        self.evicted = 0

    def __call__(self, conn: socket.socket, release: Callable[[], None]) -> None:
        loop = asyncio.get_running_loop()
        protocol = Counted(self.factory(), release, self.stall_timeout_s, self.live)
        task = loop.create_task(loop.connect_accepted_socket(lambda: protocol, conn))

        def settled(task: asyncio.Task[object]) -> None:
            if task.cancelled() or task.exception() is not None:
                conn.close()
                release()

        task.add_done_callback(settled)

    @contextlib.contextmanager
    def busy(self, transport: asyncio.BaseTransport | None) -> Iterator[None]:
        """While a request on ``transport`` is answered: its connection is not idle."""
        conn = None if transport is None else self.live.get(transport)
        if conn is None:
            yield
            return
        conn.requests += 1
        try:
            yield
        finally:
            conn.requests -= 1
            conn.touch()

    def evict_idlest(self) -> float:
        """Close the connection idle longest if it has been for ``evict_idle_s`` and return 0.

        Else the seconds until it will have been (``inf``: every connection is
        answering a request or closing).
        """
        now = asyncio.get_running_loop().time()
        for conn in self.live.values():  # idlest first; the busy and closing are skipped
            if not conn.idle:
                continue
            wait_s = conn.active_s + self.evict_idle_s - now
            if wait_s > 0:
                return wait_s
            conn.evict()
            self.evicted += 1
            return 0.0
        return math.inf
