"""The soak's slow clients: hundreds of half-sent requests held open on the HTTP port and the control socket.

A ``slow_clients`` fault (:mod:`compd.sim.soakfaults`) opens, for a while,
:data:`HTTP_PER_SLOT` connections per slot of the status page's server, or
:data:`CONTROL_PER_SLOT` per slot of the control socket, or both; each sends
half a request and sits, as a slowloris does. The servers hold at most their
cap of them (:mod:`compd.service.control.peers`): the rest wait in the kernel's queue
or, on the control socket, are told ``busy`` and closed. Meanwhile the soak
asks for the status as an operator would, over HTTP and over the control
socket, scrapes ``/metrics`` as Prometheus would, and counts the episode's
ticks and the heartbeats the PLC receives.

Judged: a status request or a scrape that gets no answer (a ``busy`` refusal
is an answer: the soak's clients are the daemon's own user, who may take every
slot), and ticks whose heartbeat the PLC never received during an episode
(the loop must keep ticking and writing). Measured: the longest real time
between two ticks during an episode. Over HTTP the status waits in the
kernel's queue until a slot frees: the idle timeout cuts a held connection,
or the episode ends and the slow clients give up.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from compd.errors import CompdError
from compd.service.control.socket import MAX_CONNECTIONS, request

if TYPE_CHECKING:
    from compd.service.daemon import Service
    from compd.service.loop.compensator import TickRecord
    from compd.sim.soakwitness import SoakResult, Witness

#: Slow clients per connection the server may hold: most of them wait in the kernel's queue.
HTTP_PER_SLOT = 4
CONTROL_PER_SLOT = 2
HALF_HTTP = b"GET /status.json HTTP/1.1\r\nHost: compd\r\nX-Slow: "
HALF_CONTROL = b'{"cmd": "sta'
#: How long (real s) a status request may wait for its answer before it counts as unanswered.
PROBE_TIMEOUT_S = 30.0
#: Tries (real s apart) of the status after an episode, while the server frees the slots.
AFTER_TRIES, AFTER_PAUSE_S = 100, 0.02


class SlowClients:
    """One ``slow_clients`` episode from :meth:`begin` to :meth:`end`; its counts go into ``result``."""

    def __init__(
        self, variant: str, span_s: tuple[float, float], witness: Witness, result: SoakResult
    ) -> None:
        self.variant = variant
        self.start_s, self.end_s = span_s
        self.period_s = 1.0
        self.witness = witness
        self.result = result
        self.socks: list[socket.socket] = []
        self.ticks = 0
        self._heartbeats0 = witness.heartbeats
        self._last_real_s: float | None = None
        self._over = asyncio.Event()

    async def begin(self, service: Service, serving: Callable[[], bool]) -> asyncio.Task[None]:
        """Open the slow clients the variant names on ``service``, each sending half a request.

        Returns the task that asks for the status meanwhile (:meth:`probe`).
        ``serving``: whether ``service`` is still running (a verdict only then).
        """
        loop = asyncio.get_running_loop()
        config = service.config
        self.period_s = config.doc.period_s
        http_port = service.http.port if service.http is not None else None
        http_slots = config.doc.http.max_connections if config.doc.http is not None else 0
        control = config.control_socket
        targets: list[tuple[int, object, bytes, int]] = []
        if self.variant in ("http", "both") and http_port is not None:
            count = HTTP_PER_SLOT * http_slots
            targets.append((socket.AF_INET, ("127.0.0.1", http_port), HALF_HTTP, count))
        if self.variant in ("socket", "both"):
            count = CONTROL_PER_SLOT * (MAX_CONNECTIONS + 1)
            targets.append((socket.AF_UNIX, str(control), HALF_CONTROL, count))
        for family, address, half, count in targets:
            for _ in range(count):
                sock = socket.socket(family, socket.SOCK_STREAM)
                sock.setblocking(False)
                self.socks.append(sock)
                with contextlib.suppress(OSError):
                    await loop.sock_connect(sock, address)  # type: ignore[arg-type]
                    sock.send(half)
        self.result.slow_clients += len(self.socks)
        return asyncio.create_task(self.probe(http_port, control, serving))

    def tick(self, record: TickRecord) -> None:
        """A tick of the service: counted when within the episode, its real gap to the last measured."""
        if not self.start_s <= record.t_s < self.end_s:
            return
        now = time.perf_counter()
        if self._last_real_s is not None:
            gap_s = now - self._last_real_s
            self.result.largest_tick_gap_s = max(self.result.largest_tick_gap_s, gap_s)
        self._last_real_s = now
        self.ticks += 1

    async def end(self) -> None:
        """The slow clients give up; ticks whose heartbeat the PLC missed meanwhile are counted."""
        for sock in self.socks:
            sock.close()
        self.socks = []
        self._over.set()
        expected = round((self.end_s - self.start_s) / self.period_s)
        received = self.witness.heartbeats - self._heartbeats0
        self.result.heartbeats_missed += max(0, expected - min(received, self.ticks))

    async def probe(
        self, http_port: int | None, control: Path, serving: Callable[[], bool]
    ) -> None:
        """Ask for the status over HTTP and the control socket, and scrape, during the episode; the status after it."""
        asks = [self._control(control)]
        if http_port is not None:
            asks += [_http_get(http_port, "/status.json"), _http_get(http_port, "/metrics")]
        control_outcome, *http = await asyncio.gather(*asks)
        for outcome in (control_outcome, *http[:1]):
            self._count(outcome, serving())
        for outcome in http[1:]:
            self._scraped(outcome, serving())
        await self._over.wait()
        for _ in range(AFTER_TRIES):  # the slots free as the server sees the clients gone
            outcome = await self._control(control)
            if outcome != "busy" or not serving():
                break
            await asyncio.sleep(AFTER_PAUSE_S)
        self._count("unanswered" if outcome == "busy" else outcome, serving())

    async def _control(self, control: Path) -> str:
        try:
            reply = await request(control, {"cmd": "status"}, timeout_s=PROBE_TIMEOUT_S)
        except CompdError:
            return "unanswered"
        if reply.get("ok"):
            return "answered"
        return "busy" if str(reply.get("error", "")).startswith("busy") else "unanswered"

    def _count(self, outcome: str, serving: bool) -> None:
        if outcome == "answered":
            self.result.status_answered += 1
        elif outcome == "busy":
            self.result.status_busy += 1
        elif serving:  # a service gone meanwhile (killed, stopped) owes no answer
            self.result.status_unanswered += 1
            self.result.errors.append(f"slow clients ({self.variant}): a status went unanswered")

    def _scraped(self, outcome: str, serving: bool) -> None:
        if outcome == "answered":
            self.result.scrapes_answered += 1
        elif serving:
            self.result.scrapes_unanswered += 1
            self.result.errors.append(f"slow clients ({self.variant}): a /metrics scrape failed")


async def _http_get(port: int, path: str) -> str:
    """``GET path`` as a browser or a scraper sends it: ``answered`` on a 200."""
    try:
        async with asyncio.timeout(PROBE_TIMEOUT_S):
            reader, writer = await asyncio.open_connection("127.0.0.1", port)
            try:
                writer.write(
                    f"GET {path} HTTP/1.1\r\nHost: compd\r\nConnection: close\r\n\r\n".encode()
                )
                await writer.drain()
                head = await reader.readline()
                await reader.read()
            finally:
                writer.close()
    except (OSError, TimeoutError):
        return "unanswered"
    return "answered" if head.split(b" ")[1:2] == [b"200"] else "unanswered"
