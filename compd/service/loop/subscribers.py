"""Everything that follows the loop, behind one protocol: ``on_tick(snapshot)``.

The recorder, telemetry, the metrics and page, the systemd notifier, the state
saver, the soak's witness and the probe learner each register once (built by
:mod:`compd.service.build` from the config) and are given the same
:class:`~compd.service.loop.snapshot.TickSnapshot` after the tick has written
to the machine. Adding one is a class and a line in the builder; the loop names
none of them.

No subscriber can cost the machine a tick: each is called under its own guard,
after the offsets are written. One that raises is a fault episode of its own
(one ERROR line when it starts failing, one INFO when it works again; it is
called again every tick); one that takes longer than its share of the period
is a "slow" episode, logged the same way. The others are called as usual.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from typing import Protocol

import structlog

from compd.errors import CompdError
from compd.faultlog import EventSink, FaultLog
from compd.service.loop.compensator import TickRecord
from compd.service.loop.snapshot import TickSnapshot

log = structlog.get_logger("compd.service.loop.subscribers")

#: The share of the loop period one subscriber may take before it is a "slow" fault episode.
SLOW_SHARE = 0.25


class Subscriber(Protocol):
    """One consumer of the loop's snapshots; ``name`` is what its fault episodes say.

    Optionally ``async begin()`` (started before the first tick: a server, a connection)
    and ``async end(*, killed)`` (at shutdown: files closed, the last state saved; with
    ``killed``, only what the OS would close), and ``reads_cpu = True`` where it reads
    :attr:`TickSnapshot.cpu_s <compd.service.loop.snapshot.TickSnapshot.cpu_s>` (NaN otherwise).
    """

    name: str

    def on_tick(self, snapshot: TickSnapshot) -> None:
        """Take one tick; cheap (a share of the period): slow work goes to a thread or a queue."""


class Subscribers:
    """The registered subscribers, called in registration order, each under its own guard."""

    def __init__(self, period_s: float, *, sink: EventSink | None = None) -> None:
        #: The time one subscriber may take (real seconds) before it is logged as slow.
        self.budget_s = SLOW_SHARE * period_s
        self.sink = sink
        self._entries: list[_Entry] = []
        #: A subscriber reads each tick's CPU time (``reads_cpu``): the loop measures it then.
        self.read_cpu = False

    def add(self, subscriber: Subscriber) -> None:
        """Register ``subscriber`` (once: a second with the same name is a programming error)."""
        if any(entry.subscriber.name == subscriber.name for entry in self._entries):
            raise CompdError(f"a tick subscriber named {subscriber.name!r} is registered already")
        self._entries.append(_Entry(subscriber, self.sink))
        self.read_cpu = self._reads_cpu()

    def remove(self, name: str) -> None:
        """Stop calling the subscriber named ``name`` (nothing if none is)."""
        self._entries = [e for e in self._entries if e.subscriber.name != name]
        self.read_cpu = self._reads_cpu()

    def _reads_cpu(self) -> bool:
        return any(getattr(e.subscriber, "reads_cpu", False) for e in self._entries)

    def __iter__(self) -> Iterator[Subscriber]:
        return (entry.subscriber for entry in self._entries)

    def __len__(self) -> int:
        return len(self._entries)

    def publish(self, snapshot: TickSnapshot) -> None:
        """Give ``snapshot`` to each subscriber; a failure or an overrun is logged, never raised."""
        # One clock reading between two subscribers: the end of one is the start of the next.
        now_s = time.perf_counter()
        for entry in self._entries:
            now_s = entry.call(snapshot, self.budget_s, now_s)

    async def begin(self) -> None:
        """Start, in registration order, the subscribers with something to start (``begin``: a server
        to listen, a broker to connect to); one that cannot start ends those started and raises."""
        started: list[Subscriber] = []
        try:
            for subscriber in self:
                begin = getattr(subscriber, "begin", None)
                if begin is not None:
                    await begin()
                    started.append(subscriber)
        except BaseException:
            await _end_each(started, killed=False)
            raise

    async def end(self, *, killed: bool = False) -> None:
        """End every subscriber (``end``), in registration order; one that fails is logged, the rest end.

        ``killed``: as SIGKILL would leave them (sockets closed, nothing saved or sent).
        """
        await _end_each(list(self), killed=killed)

    def faults(self) -> dict[str, int]:
        """Fault episodes so far (failing or slow) per subscriber name, for the status and metrics."""
        return {e.subscriber.name: e.failing.episodes + e.slow.episodes for e in self._entries}


class _Entry:
    def __init__(self, subscriber: Subscriber, sink: EventSink | None) -> None:
        self.subscriber = subscriber
        self.failing = FaultLog(log, subscriber=subscriber.name)
        self.slow = FaultLog(log, level="warning", subscriber=subscriber.name)
        self.failing.sink = self.slow.sink = sink

    def call(self, snapshot: TickSnapshot, budget_s: float, started_s: float) -> float:
        """Call the subscriber (started at ``started_s``, ``perf_counter``); returns when it ended."""
        try:
            self.subscriber.on_tick(snapshot)
        except Exception as exc:
            self.failing.failed("tick subscriber failed", error=f"{type(exc).__name__}: {exc}")
        else:
            if self.failing.active:  # (cleared() does nothing otherwise: no call every tick)
                self.failing.cleared("tick subscriber works again")
        ended_s = time.perf_counter()
        took_s = ended_s - started_s
        if took_s > budget_s:
            self.slow.failed(
                "tick subscriber slow", took_ms=round(took_s * 1e3, 1), budget_ms=budget_s * 1e3
            )
        elif self.slow.active:
            self.slow.cleared("tick subscriber on time again")
        return ended_s


class TickCallback:
    """A plain function of each tick's record as a subscriber (tests, the soak's witness, the live view)."""

    def __init__(self, name: str, function: Callable[[TickRecord], None]) -> None:
        self.name = name
        self.function = function

    def on_tick(self, snapshot: TickSnapshot) -> None:
        self.function(snapshot.record)


async def _end_each(subscribers: list[Subscriber], *, killed: bool) -> None:
    for subscriber in subscribers:
        end = getattr(subscriber, "end", None)
        if end is None:
            continue
        try:
            await end(killed=killed)
        except Exception as exc:
            log.error("tick subscriber failed to end", subscriber=subscriber.name, error=str(exc))
