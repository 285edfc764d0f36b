"""Probe results over MQTT: a CMM station or a gauge's PC publishes them to the machine.

A request on ``<prefix>/<machine_id>/cmd/probe``::

    {"request_id": "cmm-0412", "axis": "Z", "measured_um": 3.2,
     "touched_at_unix_s": 1795858200.0, "measures": "residue", "requested_by": "cmm-2"}

is checked as a ``cmd/model_load`` is (never a retained one, refused before it
is parsed: a retained probe would be taken again at every reconnect; then
JSON parsed in a worker thread, a usable id, no number compd does not read), taken as the control socket's ``probe`` is
(:meth:`compd.service.daemon.Service.take_probe`), and answered on
``reply/<request_id>`` with what the update did.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from typing import Any

import structlog

from compd.errors import CompdError
from compd.faultlog import Event, EventSink
from compd.service.fleet.remoteload import checked_request
from compd.service.fleet.wirecheck import Parser, cheap_request_id

log = structlog.get_logger("compd.service.fleet.remoteprobe")

#: The command kind (``cmd/probe``).
COMMAND = "probe"
#: A probe request is a few hundred bytes; anything larger is not one.
MAX_PAYLOAD_BYTES = 4096


class RemoteProbes:
    """Takes ``cmd/probe`` requests with ``take`` and answers each with ``reply``."""

    def __init__(
        self,
        take: Callable[[dict[str, Any]], Awaitable[dict[str, Any]]],
        reply: Callable[[str, dict[str, Any]], object],
        events: EventSink,
    ) -> None:
        self.take = take
        self.reply = reply
        self.events = events
        self.parser = Parser()

    async def handle(self, payload: bytes, *, retained: bool = False) -> None:
        try:
            if retained:  # judged on the flag, before a byte is parsed
                raise CompdError(
                    "a retained probe is refused: it would be taken again at every reconnect"
                )
            parsed = await self.parser.parse(payload)
            request = checked_request(parsed)
        except CompdError as exc:
            request_id = cheap_request_id(payload)
            log.error("remote probe refused", request_id=request_id, reason=str(exc))
            self.events(Event("probe_refused", "remote probe refused", {"reason": str(exc)}))
            if request_id is not None:
                self.reply(request_id, {"request_id": request_id, "ok": False, "error": str(exc)})
            return
        request_id = request["request_id"]
        answer: dict[str, Any] = {"request_id": request_id}
        try:
            if "reset" in request:
                raise CompdError("a reset is made at the machine: compd model probe --reset")
            if parsed.unread is not None:
                raise CompdError(f"the request holds a number compd does not read: {parsed.unread}")
            by = str(request.get("requested_by", "mqtt"))[:64]
            message = {k: v for k, v in request.items() if k not in ("request_id", "requested_by")}
            answer |= {"ok": True} | await self.take(message | {"source": f"mqtt:{by}"})
        except CompdError as exc:
            log.error("remote probe refused", request_id=request_id, reason=str(exc))
            self.events(Event("probe_refused", "remote probe refused", {"reason": str(exc)}))
            answer |= {"ok": False, "error": str(exc)}
        self.reply(request_id, answer)
