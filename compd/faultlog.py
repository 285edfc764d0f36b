"""Logging by fault episode: ERROR once when a fault starts, DEBUG while it lasts, INFO when it clears.

A fault that repeats every tick (a dead link, a full disk, a PLC that
accepts connections but never answers) must not flood the journal: the
first failure of an episode is news for the operator, its repeats are
detail for whoever debugs, and the recovery is news again. Every place that
can fail over and over reports through one :class:`FaultLog`, so the rule
holds everywhere and is tested once.

The same episodes, with model loads and failures, are also told to an
:data:`EventSink` where one is attached (the MQTT telemetry,
:mod:`compd.service.fleet.telemetry`): structured events, never parsed from the log.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class Event:
    """Something an operator's dashboard should hear of at once, beside the journal.

    ``kind``: ``fault`` (an episode starts), ``cleared`` (it ends; never
    without its ``fault``), ``reconnected`` (after the ``cleared`` of a
    link's episode), ``model_loaded``, ``model_switched``, ``model_blended``,
    ``model_failed``;
    ``message``: the log line's event; ``details``: its JSON-able fields.
    """

    kind: str
    message: str
    details: dict[str, Any] = field(default_factory=dict)


#: Where events go: called in the loop's thread, it must return at once (queue, never I/O).
EventSink = Callable[[Event], None]


class FaultLog:
    """The log lines of one kind of fault; ``context`` is added to each (e.g. ``driver="plc"``).

    ``level`` is the level of an episode's first line: ``error``, or
    ``warning`` for a fault the caller still tolerates (a missed reply);
    ``end_level`` that of its last (``error`` where both ends must reach
    ``journalctl -p err``: a sensor replaced by its prediction).
    """

    def __init__(
        self, logger: Any, *, level: str = "error", end_level: str = "info", **context: Any
    ) -> None:
        self._log = logger
        self._start = getattr(logger, level)
        self._end = getattr(logger, end_level)
        self._context = context
        #: A fault episode is under way: it failed and has not cleared since.
        self.active = False
        #: Episodes so far (each one logged at ERROR once).
        self.episodes = 0
        #: Told of each episode's start and end, where attached.
        self.sink: EventSink | None = None

    def failed(self, event: str, **details: Any) -> None:
        """A failure: ERROR (``level``) ``event`` if it starts an episode, else DEBUG ``event`` + " again"."""
        if self.active:
            self._log.debug(f"{event} again", **self._context, **details)
            return
        self.active = True
        self.episodes += 1
        self._start(event, **self._context, **details)
        if self.sink is not None:
            self.sink(Event("fault", event, {**self._context, **details}))

    def cleared(self, event: str, *, also: str | None = None, **details: Any) -> None:
        """A success: INFO ``event`` if it ends an episode, nothing otherwise.

        The sink hears ``cleared`` (every episode ends as it started, with one
        event of its own), then ``also`` where given (``reconnected``: what
        the end was, for a dashboard that counts reconnections).
        """
        if self.active:
            self.active = False
            self._end(event, **self._context, **details)
            if self.sink is not None:
                self.sink(Event("cleared", event, {**self._context, **details}))
                if also is not None:
                    self.sink(Event(also, event, {**self._context, **details}))
