"""Probe results over MQTT: a CMM station or a gauge's PC publishes them to the machine.

A request on ``<prefix>/<machine_id>/cmd/probe``::

    {"request_id": "cmm-0412", "axis": "Z", "measured_um": 3.2,
     "touched_at_unix_s": 1795858200.0, "measures": "residue", "requested_by": "cmm-2"}

is checked as a ``cmd/model_load`` is (JSON, a usable id, no number compd does
not read, never a retained one: a retained probe would be taken again at
every reconnect), taken as the control socket's ``probe`` is
(:meth:`compd.service.daemon.Service.take_probe`), and answered on
``reply/<request_id>`` with what the update did.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from typing import Any

import structlog

from compd.errors import CompdError
from compd.faultlog import Event, EventSink
from compd.service.fleet.remoteload import parse_request, unread_number

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

    async def handle(self, payload: bytes, *, retained: bool = False) -> None:
        try:
            request = parse_request(payload)
        except CompdError as exc:
            log.error("remote probe ignored", error=str(exc))
            self.events(Event("probe_refused", "remote probe ignored", {"reason": str(exc)}))
            return
        request_id = request["request_id"]
        answer: dict[str, Any] = {"request_id": request_id}
        try:
            if retained:
                raise CompdError(
                    "a retained probe is refused: it would be taken again at every reconnect"
                )
            if "reset" in request:
                raise CompdError("a reset is made at the machine: compd model probe --reset")
            if (unread := unread_number(request)) is not None:
                raise CompdError(f"the request holds a number compd does not read: {unread}")
            by = str(request.get("requested_by", "mqtt"))[:64]
            message = {k: v for k, v in request.items() if k not in ("request_id", "requested_by")}
            answer |= {"ok": True} | await self.take(message | {"source": f"mqtt:{by}"})
        except CompdError as exc:
            log.error("remote probe refused", request_id=request_id, reason=str(exc))
            self.events(Event("probe_refused", "remote probe refused", {"reason": str(exc)}))
            answer |= {"ok": False, "error": str(exc)}
        self.reply(request_id, answer)
