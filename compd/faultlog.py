"""Logging by fault episode: ERROR once when a fault starts, DEBUG while it lasts, INFO when it clears.

A fault that repeats every tick (a dead link, a full disk, a PLC that
accepts connections but never answers) must not flood the journal: the
first failure of an episode is news for the operator, its repeats are
detail for whoever debugs, and the recovery is news again. Every place that
can fail over and over reports through one :class:`FaultLog`, so the rule
holds everywhere and is tested once.
"""

from __future__ import annotations

from typing import Any


class FaultLog:
    """The log lines of one kind of fault; ``context`` is added to each (e.g. ``driver="plc"``).

    ``level`` is the level of an episode's first line: ``error``, or
    ``warning`` for a fault the caller still tolerates (a missed reply).
    """

    def __init__(self, logger: Any, *, level: str = "error", **context: Any) -> None:
        self._log = logger
        self._start = getattr(logger, level)
        self._context = context
        #: A fault episode is under way: it failed and has not cleared since.
        self.active = False
        #: Episodes so far (each one logged at ERROR once).
        self.episodes = 0

    def failed(self, event: str, **details: Any) -> None:
        """A failure: ERROR (``level``) ``event`` if it starts an episode, else DEBUG ``event`` + " again"."""
        if self.active:
            self._log.debug(f"{event} again", **self._context, **details)
            return
        self.active = True
        self.episodes += 1
        self._start(event, **self._context, **details)

    def cleared(self, event: str, **details: Any) -> None:
        """A success: INFO ``event`` if it ends an episode, nothing otherwise."""
        if self.active:
            self.active = False
            self._log.info(event, **self._context, **details)
