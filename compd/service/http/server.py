"""The read-only HTTP server of a running service: ``/metrics`` for Prometheus, ``/`` for people.

One aiohttp server on the service's own event loop (config section ``http``,
:class:`compd.service.config.docs.HttpDoc`), so every answer is built between
two ticks from the live objects, consistent with ``compd status``, with no
lock and no thread:

- ``GET /metrics``: the Prometheus text format (:mod:`compd.service.http.metrics`);
- ``GET /``: the status page, static HTML, CSS and a small script that draws
  what the two JSON documents below hold (no CDN: a shop floor is offline);
- ``GET /status.json``: the snapshot ``compd status --json`` prints
  (:mod:`compd.service.loop.statusview`);
- ``GET /history.json?points=N``: the last hour of ticks (:mod:`compd.service.http.history`);
- ``GET /healthz``: for load balancers and probes, ``200`` while ticks are on time and the
  outputs healthy, else ``503``; both with ``{"healthy": ..., "problems": [...]}``
  (:func:`compd.service.loop.statusview.health_problems`) and ``"warnings"``: what is
  not well though compensation goes on (the state not saved, inputs the sensors cannot
  verify to an axis's tolerance), never a 503.

Nothing can be changed through it: only GET and HEAD are answered, any other
method is ``405 Method Not Allowed``, and the page carries a content
security policy with ``form-action 'none'``. Loading a model stays the
control socket's, behind its access list. Names come from config and model
files, so the page sets them as text, never as markup.

No client can starve the daemon (:mod:`compd.service.control.peers`): at most
``http.max_connections`` are open at once (fewer where the open-files limit
is low), the rest wait in the kernel's queue, and a connection with no
request under way for ``http.idle_timeout_s`` (one sending its headers
slowly, or idle between requests) is closed, as is one that leaves an
answer unread that long. Nor can clients starve a scraper: with every
connection taken, the one idle longest is closed for the next in the queue
(:class:`compd.service.control.peers.Served`), so 1,000 clients that connect and
send nothing hold ``/metrics`` up for milliseconds, not for the idle timeout
once per ``max_connections`` of them.
"""

from __future__ import annotations

import asyncio
import json
import socket
import time
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import TYPE_CHECKING

import structlog
from aiohttp import web

from compd.errors import CompdError
from compd.files.modelfigures import model_figures
from compd.service.control.peers import FdBudget, Listener, Served
from compd.service.control.socket import jsonable
from compd.service.http.history import RecentFaults, TickHistory
from compd.service.http.metrics import ServiceMetrics
from compd.service.http.view import ServiceView
from compd.service.loop.safety import Flag, Level
from compd.service.loop.snapshot import TickSnapshot
from compd.service.loop.statusview import health_problems

if TYPE_CHECKING:
    from compd.service.loop.slots import ModelSlot

log = structlog.get_logger("compd.service.http.server")

#: The page's files, next to this module: served as they are.
PAGE_DIR = Path(__file__).parent / "statuspage"
PAGE_FILES = {
    "/": ("index.html", "text/html"),
    "/page.js": ("page.js", "text/javascript"),
    "/page.css": ("page.css", "text/css"),
    "/favicon.svg": ("favicon.svg", "image/svg+xml"),
}
#: Most rows ``/history.json`` answers with, whatever ``points`` asks.
MAX_POINTS = 3600
READ_ONLY = frozenset({"GET", "HEAD"})
#: An answer asked for this close to the next tick (real s, either side) waits for that tick to finish.
TICK_GUARD_S = 0.05
#: Clients the kernel queues while all connections are taken (they cost the daemon no descriptor;
#: Linux caps it at ``net.core.somaxconn``, 4096 by default since 5.4). A full queue drops new
#: clients' SYNs, which they resend after 1, 3, 7 s: a flood of 1,100 reconnecting clients
#: held a scrape up for seconds at 1024, so the queue holds more than such a flood.
BACKLOG = 4096
HEADERS = {
    "Content-Security-Policy": (
        "default-src 'none'; script-src 'self'; style-src 'self'; connect-src 'self'; "
        "img-src 'self'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'"
    ),
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
    "Cache-Control": "no-store",
}

Handler = Callable[[web.Request], Awaitable[web.StreamResponse]]


class StatusServer:
    """The service's metrics, its history and the server answering for them; :meth:`start`, then :meth:`close`."""

    #: It observes each tick's CPU (``compd_tick_cpu_seconds``): the loop measures it for it.
    reads_cpu = True

    def __init__(
        self,
        service: ServiceView,
        *,
        host: str,
        port: int,
        max_connections: int,
        idle_timeout_s: float,
        budget: FdBudget | None = None,
    ) -> None:
        self.service = service
        self.host = host
        self.requested_port = port
        self.max_connections = max_connections
        self.idle_timeout_s = idle_timeout_s
        self.budget = budget
        self.metrics = ServiceMetrics(service)
        doc = service.config.doc
        self.history = TickHistory(list(doc.outputs), list(doc.signals), doc.period_s)
        self.faults = RecentFaults()
        for name, link in service.links.items():
            link.observe = self.metrics.io_observer(name)
        self._pages = {
            route: (((PAGE_DIR / file).read_bytes()), kind)
            for route, (file, kind) in PAGE_FILES.items()
        }
        #: When the last tick started and the next is due (``time.perf_counter()`` s): the
        #: real period is measured, as the clock may be scaled or virtual.
        self._last_tick_real_s: float | None = None
        self._next_tick_real_s = -float("inf")  # time.perf_counter() time
        self._ticked = asyncio.Event()
        self._served: Served | None = None
        self.app = web.Application(middlewares=[self._in_use, _read_only, self._clear_of_ticks])
        for route in PAGE_FILES:
            self.app.router.add_get(route, self._page)
        self.app.router.add_get("/metrics", self._metrics)
        self.app.router.add_get("/status.json", self._status)
        self.app.router.add_get("/history.json", self._history)
        self.app.router.add_get("/page.json", self._page_json)
        self.app.router.add_get("/healthz", self._healthz)
        self._runner: web.AppRunner | None = None
        self._listener: Listener | None = None

    name = "http"

    async def begin(self) -> None:
        await self.start()

    async def end(self, *, killed: bool) -> None:
        """Stop listening (killed too: the OS closes the port)."""
        await self.close()

    def on_tick(self, snapshot: TickSnapshot) -> None:
        """What each tick leaves here: its lateness and CPU (s), a row of history; answers held for it go on."""
        self.metrics.observe_tick(snapshot.lateness_s, snapshot.cpu_s)
        self.history.append(snapshot.record)
        self.faults.update(snapshot.record, self.service.compensator, self.service.links)
        started_real_s = snapshot.started_real_s
        if self._last_tick_real_s is not None:
            self._next_tick_real_s = 2 * started_real_s - self._last_tick_real_s
        self._last_tick_real_s = started_real_s
        self._ticked.set()
        self._ticked = asyncio.Event()

    @property
    def port(self) -> int:
        """The port listened on (the one the OS chose for ``port: 0``)."""
        assert self._listener is not None, "not started"
        return int(self._listener.sock.getsockname()[1])

    @property
    def connections(self) -> int:
        """The clients connected now (at most the cap; others wait in the kernel's queue)."""
        return 0 if self._listener is None else self._listener.open

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}/"

    async def start(self) -> None:
        """Listen; a port in use or an address not of this host is a CompdError naming the config."""
        try:
            sock = socket.create_server(
                (self.host, self.requested_port),
                family=socket.AF_INET6 if ":" in self.host else socket.AF_INET,
                backlog=BACKLOG,
            )
        except OSError as exc:
            raise CompdError(
                f"{self.service.config.path}: http: cannot listen on {self.host}:{self.requested_port}: "
                f"{exc.strerror or exc}. Give 'http.port' a free port (another compd may hold this one), "
                "or 'http.listen' an address of this host"
            ) from exc
        # aiohttp's keep-alive timer runs from the connection's start and from each
        # answer, and closes a connection still waiting for a whole request: it is
        # the header timeout and the idle timeout both.
        runner = web.AppRunner(
            self.app, access_log=None, handle_signals=False, keepalive_timeout=self.idle_timeout_s
        )
        await runner.setup()
        budget = self.budget or FdBudget()
        cap = budget.take(self.max_connections, "http")
        assert runner.server is not None
        served = Served(runner.server, stall_timeout_s=self.idle_timeout_s)
        self._listener = Listener(sock, cap, served, name="http", evict=served.evict_idlest)
        self._served = served
        self._listener.start()
        self._runner = runner
        log.info(
            "http server listening", url=self.url, metrics=f"{self.url}metrics", connections=cap
        )

    async def close(self) -> None:
        if self._listener is not None:
            await self._listener.close()  # no new connections while the open ones end
        if self._runner is not None:
            await self._runner.cleanup()
            self._runner = None
        self._listener = None

    @property
    def evicted(self) -> int:
        """Idle connections closed so far to serve new clients with every slot taken."""
        return 0 if self._served is None else self._served.evicted

    @web.middleware
    async def _in_use(self, request: web.Request, handler: Handler) -> web.StreamResponse:
        """Mark the connection busy while its request is answered: it is never closed for another."""
        if self._served is None:
            return await handler(request)
        with self._served.busy(request.transport):
            return await handler(request)

    @web.middleware
    async def _clear_of_ticks(self, request: web.Request, handler: Handler) -> web.StreamResponse:
        """Answer in the gap after a tick, never in the last moments before one.

        Building an answer takes about a millisecond of the loop; one started just
        before a deadline would make that tick late, and a scraper whose interval
        equals the period would hit the same phase every time. So a request that
        arrives within :data:`TICK_GUARD_S` of the next tick waits (at most twice
        that) for it to finish first: Prometheus's timeout is seconds.
        """
        to_tick_s = self._next_tick_real_s - time.perf_counter()
        if -TICK_GUARD_S < to_tick_s < TICK_GUARD_S:
            try:
                async with asyncio.timeout(2 * TICK_GUARD_S):
                    await self._ticked.wait()
            except TimeoutError:
                pass  # the tick is late or the clock stands still (a test): answer anyway
        return await handler(request)

    async def _page(self, request: web.Request) -> web.Response:
        body, kind = self._pages[request.path]
        return web.Response(body=body, content_type=kind, charset="utf-8")

    async def _metrics(self, request: web.Request) -> web.Response:
        body, content_type = self.metrics.render(request.headers.get("Accept", ""))
        response = web.Response(body=body)
        response.headers["Content-Type"] = content_type
        return response

    async def _status(self, request: web.Request) -> web.Response:
        return _json(self.service.status())

    async def _healthz(self, request: web.Request) -> web.Response:
        service = self.service
        problems = health_problems(
            service.compensator,
            service.links,
            service.timing,
            clock=service.clock,
            period_s=service.config.doc.period_s,
        )
        if (probing := service.probing) is not None and (problem := probing.problem()):
            problems.append(problem)  # what the probes taught is not applied while it fails
        last = service.compensator.last
        level = None if last is None else Level(last.status & 0b11).name.lower()
        # Not a reason to restart or route around this daemon (it compensates), but not all well.
        warnings = service.not_assured()
        answer = _json(
            {"healthy": not problems, "level": level, "problems": problems, "warnings": warnings}
        )
        answer.set_status(503 if problems else 200)
        return answer

    async def _history(self, request: web.Request) -> web.Response:
        text = request.query.get("points", "720")
        try:
            points = int(text)
        except ValueError:
            raise web.HTTPBadRequest(
                text=f"'points' must be a whole number, got {text!r}"
            ) from None
        if not 1 <= points <= MAX_POINTS:
            raise web.HTTPBadRequest(text=f"'points' must be 1..{MAX_POINTS}, got {points}")
        doc = self.service.config.doc
        history = self.history.snapshot(points)
        history["units"] = {name: signal.unit for name, signal in doc.signals.items()}
        return _json(history)

    async def _page_json(self, request: web.Request) -> web.Response:
        """What the page shows beside ``/status.json``: the model's provenance, the status bits, the faults."""
        service = self.service
        comp = service.compensator
        last = comp.last
        return _json(
            {
                "config": str(service.config.path),
                # None: the config names no machine.
                "machine_id": service.config.doc.machine_id,
                "period_s": service.config.doc.period_s,
                # None: a data logger (no model).
                "model": None if (running := comp.running) is None else _model_json(running),
                "status": _status_bits(None if last is None else last.status),
                # What is not well though the level may read ok (/healthz's warnings).
                "not_assured": service.not_assured(),
                "units": {name: s.unit for name, s in service.config.doc.signals.items()},
                "faults": self.faults.as_json(),
                "model_loads": self.faults.loads_json(),
                "probe_marks": self.faults.probes_json(),
                # Per probed axis what the probes say now; None: the config probes nothing.
                "probes": None
                if (probing := service.probing) is None
                else probing.status(service.clock_wall())["axes"],
            }
        )


def _model_json(slot: ModelSlot) -> dict[str, object]:
    """The running model and its provenance, as the page shows them."""
    model_doc = slot.model_file.doc
    provenance = model_doc.provenance
    # This model's own figure on new data, as compd model check and the report lead with it.
    figures = model_figures(model_doc)
    headline = figures.headline
    expected = (
        None
        if headline is None or len(headline.percent) != 1
        else next(iter(headline.percent.values()))
    )
    return {
        "name": slot.compiled.name,
        "sha256": slot.sha256,
        "path": str(slot.model_file.path),
        "description": model_doc.description,
        "method": provenance.method,
        "created": provenance.created,
        "data": provenance.data,
        "command": provenance.command,
        "compd_version": provenance.compd_version,
        "fit_percent": provenance.fit_percent,
        "held_out_fit_percent": expected,
        # Why there is none: the folds judged another method than this model's (None: not that).
        "held_out_note": figures.not_judged(),
        "updates": len(provenance.updates),
        "extensions": len(provenance.extensions),
    }


def _status_bits(word: int | None) -> dict[str, object]:
    """The status word's level and flags by name (:mod:`compd.service.loop.safety`)."""
    if word is None:
        return {"word": None, "level": None, "flags": []}
    return {
        "word": word,
        "level": Level(word & 0b11).name.lower(),
        "flags": [flag.name.lower() for flag in Flag if word & flag],
    }


def _json(data: object) -> web.Response:
    # As the control socket answers: NaN (a value not known yet) as null, which JSON has.
    return web.Response(
        text=json.dumps(jsonable(data), allow_nan=False), content_type="application/json"
    )


@web.middleware
async def _read_only(request: web.Request, handler: Handler) -> web.StreamResponse:
    """Only GET and HEAD, on every path; every answer carries the page's security headers."""
    if request.method not in READ_ONLY:
        raise web.HTTPMethodNotAllowed(request.method, sorted(READ_ONLY), headers=HEADERS)
    try:
        response = await handler(request)
    except web.HTTPException as exc:
        exc.headers.update(HEADERS)
        raise
    response.headers.update(HEADERS)
    return response
