"""Probe results over MQTT: a CMM station or a gauge's PC publishes them to the machine.

A request on ``<prefix>/<machine_id>/cmd/probe``::

    {"request_id": "cmm-0412", "axis": "Z", "measured_um": 3.2,
     "touched_at_unix_s": 1795858200.0, "measures": "residue", "requested_by": "cmm-2"}

is checked as a ``cmd/model_load`` is (never a retained one, refused before it
is parsed: a retained probe would be taken again at every reconnect; then
JSON parsed in a worker thread, a usable id, no number compd does not read), taken as the control socket's ``probe`` is
(:meth:`compd.service.daemon.Service.take_probe`), and answered on
``reply/<request_id>`` with what the update did.

A request is taken once: its id, read from the bytes before any parse, is
checked first, and a replay (a broker's redelivery, a station's retry, an
attacker's copy) is answered with the first answer and ``"duplicate": true``,
never taken again; the ids are kept :data:`KEEP_S` (across restarts too, in
the state directory: after one the first answer is gone, and the replay says
so). A shift past the learned shift's bound is accepted at the machine only
(``compd model probe --accept-shift``), never over the broker.
"""

from __future__ import annotations

import asyncio
import time
from collections import OrderedDict
from collections.abc import Awaitable, Callable
from typing import Any

import structlog

from compd.errors import CompdError
from compd.faultlog import Event, EventSink
from compd.service.fleet.remoteload import checked_request
from compd.service.fleet.seenrequests import SeenRequests
from compd.service.fleet.wirecheck import Parser, cheap_request_id

log = structlog.get_logger("compd.service.fleet.remoteprobe")

#: The command kind (``cmd/probe``).
COMMAND = "probe"
#: A probe request is a few hundred bytes; anything larger is not one.
MAX_PAYLOAD_BYTES = 4096
#: A request id is remembered this long (s): longer than the offsets kept for a touch (12 h),
#: so a replay without a touch time (taken as now) is refused by its id.
KEEP_S = 13 * 3600.0
#: The first answers kept for a replay (the newest).
ANSWERS_KEPT = 1000
#: The file of the request ids in the state directory.
FILE = "probe_requests.json"


class RemoteProbes:
    """Takes ``cmd/probe`` requests with ``take`` and answers each with ``reply``, each id once."""

    def __init__(
        self,
        take: Callable[[dict[str, Any]], Awaitable[dict[str, Any]]],
        reply: Callable[[str, dict[str, Any]], object],
        events: EventSink,
        *,
        seen: SeenRequests | None = None,
        clock: Callable[[], float] = time.time,
    ) -> None:
        self.take = take
        self.reply = reply
        self.events = events
        self.parser = Parser()
        #: The ids taken (persisted where a path is given): a replay is refused by its id.
        self.seen = seen if seen is not None else SeenRequests(None, window_s=KEEP_S)
        self.clock = clock
        #: Per id, its first answer (or the future of one still being taken).
        self.answers: OrderedDict[str, asyncio.Future[dict[str, Any]]] = OrderedDict()
        self._replays = 0

    async def handle(self, payload: bytes, *, retained: bool = False) -> None:
        said_id = cheap_request_id(payload)  # the replay check first, before a byte is parsed
        if said_id is not None and (said_id in self.answers or self.seen.seen(said_id)):
            await self._replayed(said_id)
            return
        try:
            if retained:  # judged on the flag, before a byte is parsed
                raise CompdError(
                    "a retained probe is refused: it would be taken again at every reconnect"
                )
            parsed = await self.parser.parse(payload)
            request = checked_request(parsed)
        except CompdError as exc:
            log.error("remote probe refused", request_id=said_id, reason=str(exc))
            self.events(Event("probe_refused", "remote probe refused", {"reason": str(exc)}))
            if said_id is not None:
                self.reply(said_id, {"request_id": said_id, "ok": False, "error": str(exc)})
            return
        request_id = request["request_id"]
        if request_id in self.answers or self.seen.seen(request_id):  # an id the bytes hid
            await self._replayed(request_id)
            return
        first: asyncio.Future[dict[str, Any]] = asyncio.get_running_loop().create_future()
        self.answers[request_id] = first
        while len(self.answers) > ANSWERS_KEPT:
            self.answers.popitem(last=False)
        answer: dict[str, Any] = {"request_id": request_id}
        try:
            answer = await self._take(request, answer, parsed.unread)
        finally:
            first.set_result(answer)
        self.reply(request_id, answer)

    async def _replayed(self, request_id: str) -> None:
        """A request id seen before: the first answer again, said to be a replay; nothing taken."""
        first = self.answers.get(request_id)
        if first is None:  # taken before a restart: its answer is gone
            answer = {
                "request_id": request_id,
                "ok": False,
                "error": "already taken (before the daemon restarted): not taken again",
            }
        else:
            answer = dict(await first)
        self._replays += 1
        say = log.debug if self._replays > 1 else log.warning
        say("remote probe replayed: answered, not taken again", request_id=request_id)
        self.reply(request_id, answer | {"duplicate": True})

    async def _take(
        self, request: dict[str, Any], answer: dict[str, Any], unread: object
    ) -> dict[str, Any]:
        request_id = request["request_id"]
        try:
            if "reset" in request:
                raise CompdError("a reset is made at the machine: compd model probe --reset")
            if unread is not None:
                raise CompdError(f"the request holds a number compd does not read: {unread}")
            if "accept_shift" in request:
                raise CompdError(
                    "a shift is accepted by a person at the machine: compd model probe --accept-shift"
                )
            by = str(request.get("requested_by", "mqtt"))[:64]
            message = {k: v for k, v in request.items() if k not in ("request_id", "requested_by")}
            await self._remember(request_id)
            answer |= {"ok": True} | await self.take(message | {"source": f"mqtt:{by}"})
        except CompdError as exc:
            log.error("remote probe refused", request_id=request_id, reason=str(exc))
            self.events(Event("probe_refused", "remote probe refused", {"reason": str(exc)}))
            answer |= {"ok": False, "error": str(exc)}
        return answer

    async def _remember(self, request_id: str) -> None:
        """The id kept before the probe is offered (on disk off the loop: a restart still knows it)."""
        now = self.clock()
        self.seen.add(request_id, now, now)
        await asyncio.to_thread(self.seen.save, self.seen.content())
