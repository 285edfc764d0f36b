"""The roll-out requests a machine has taken lately: a replayed ``request_id`` is refused, across restarts too.

A request (:mod:`compd.service.fleet.remoteload`) is taken only within
:data:`WINDOW_S` of the time it says it was sent; the ids of those taken are
kept while they are inside that window (so a replay is refused by its id
inside the window and by its age after it), at most :data:`KEEP` of them, in
``<state directory>/model_requests.json`` (written atomically, as the state
file). A file that cannot be read is logged and started afresh: the age
check still holds.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import structlog

from compd.files.unreadable import write_atomic

log = structlog.get_logger("compd.service.fleet.seenrequests")

#: A request is taken within this much of its ``sent_unix_s``, either way (the sender's clock and
#: the machine's may differ by up to this much).
WINDOW_S = 600.0
#: Ids kept at most (the newest): more requests than this inside the window are not expected.
KEEP = 1000
#: The file in the state directory.
FILE = "model_requests.json"


class SeenRequests:
    """Request id -> the time it was sent, of the requests taken inside the window; ``path`` None: in memory."""

    def __init__(self, path: Path | None, *, window_s: float = WINDOW_S, keep: int = KEEP) -> None:
        self.path = path
        self.window_s = window_s
        self.keep = keep
        self.sent: dict[str, float] = {} if path is None else _read(path)

    def seen(self, request_id: str) -> bool:
        return request_id in self.sent

    def add(self, request_id: str, sent_unix_s: float, now_unix_s: float) -> None:
        """Remember ``request_id``; forget those outside the window and beyond :attr:`keep`."""
        self.sent[request_id] = sent_unix_s
        kept = sorted((t, i) for i, t in self.sent.items() if t >= now_unix_s - self.window_s)[
            -self.keep :
        ]
        self.sent = {i: t for t, i in kept}

    def content(self) -> bytes:
        """The file's text: the ids and their times."""
        return json.dumps({"schema": "compd.model_requests/1", "sent_unix_s": self.sent}).encode()

    def save(self, content: bytes) -> None:
        """Write :meth:`content` (off the event loop: it fsyncs); a failure is logged, not raised."""
        if self.path is None:
            return
        try:
            write_atomic(self.path, content)
        except OSError as exc:
            log.error(
                "cannot save the roll-out request ids: a replay after a restart is refused by its age only",
                file=str(self.path),
                error=str(exc),
            )


def _read(path: Path) -> dict[str, float]:
    try:
        doc = json.loads(path.read_bytes())
        sent = doc["sent_unix_s"]
        return {
            str(i): float(t)
            for i, t in sent.items()
            if isinstance(t, int | float) and math.isfinite(t)
        }
    except FileNotFoundError:
        return {}
    # ValueError: an integer of more than 4,300 digits; OverflowError: one of 400, as a float.
    except (OSError, ValueError, OverflowError, KeyError, TypeError, AttributeError) as exc:
        log.warning(
            "roll-out request ids not readable: starting afresh (the age check still holds)",
            file=str(path),
            error=str(exc),
        )
        return {}
