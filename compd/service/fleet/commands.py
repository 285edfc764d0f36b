"""The commands a daemon's telemetry takes: ``<prefix>/<machine_id>/cmd/<kind>``, bounded, on the loop.

With ``accept_models: true`` (never by default) the daemon subscribes to
``cmd/<kind>`` for each kind registered (:meth:`Commands.listen`;
:mod:`compd.service.fleet.remoteload` is the one command, a model rolled out to
the fleet) while it publishes, and answers on ``reply/<request_id>``. A
command's payload is bounded (the connection's MQTT 5 Maximum Packet Size:
the broker drops a larger message before sending it; and its length is
checked again here, before a byte is parsed: refused with one log line, an
event and an answer to the request id read from the bytes where there is one,
:func:`~compd.service.fleet.wirecheck.cheap_request_id`) and handed from
paho's thread to the event loop with its retain flag, never acted on in
paho's thread. At most :data:`MAX_HANDLING` messages are handled at once (a
flood is refused as a too-large one is), so the bytes waiting are bounded too;
the handlers parse off the loop (:mod:`compd.service.fleet.wirecheck`).
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Awaitable, Callable
from typing import Any

import paho.mqtt.client as mqtt
import structlog

from compd.faultlog import Event, EventSink
from compd.service.fleet.mqttlink import Topics
from compd.service.fleet.wirecheck import cheap_request_id

log = structlog.get_logger("compd.service.fleet.telemetry")

#: A command's handler: ``await handler(payload, retained=flag)`` (the broker's retain flag).
Handler = Callable[..., Awaitable[None]]
#: The answer to a command refused before its handler: ``reply(request_id, fields)``.
Reply = Callable[[str, dict[str, Any]], object]

#: A command's packet beyond its payload, at most: fixed header, topic, packet id, properties.
PACKET_OVERHEAD_BYTES = 1024
#: The largest packet taken without commands: the acknowledgements of what is published.
MAX_PACKET_BYTES = 64 * 1024
#: Commands handled at once, at most (their payloads held meanwhile): more are refused, answered.
MAX_HANDLING = 8


class Commands:
    """``cmd/<kind>`` -> (handler, largest payload in bytes); dispatched onto the event loop."""

    def __init__(self, topics: Topics, events: EventSink, reply: Reply | None = None) -> None:
        self.topics = topics
        self.events = events
        #: Answers a command refused here (``reply/<request_id>``); None: refusals are logged only.
        self.reply = reply
        self.kinds: dict[str, tuple[Handler, int]] = {}
        self.loop: asyncio.AbstractEventLoop | None = None
        self._handling: set[asyncio.Task[None]] = set()

    def listen(self, kind: str, handler: Handler, *, max_bytes: int) -> None:
        """Act on ``cmd/<kind>``: ``await handler(payload, retained=...)`` on the loop.

        A message whose packet would exceed ``max_bytes`` and
        :data:`PACKET_OVERHEAD_BYTES` is dropped by the broker
        (:attr:`max_packet_bytes`); a payload over ``max_bytes`` that arrives
        all the same (another command's bound is larger) is refused unparsed:
        one log line, a ``fault`` event, and an answer to the request id its
        bytes name, where they name one.
        """
        self.kinds[kind] = (handler, max_bytes)

    @property
    def max_packet_bytes(self) -> int:
        """The Maximum Packet Size told to the broker: the largest command's and its packet's overhead."""
        commands = (
            max_bytes + len(self.topics.of(f"cmd/{kind}").encode()) + PACKET_OVERHEAD_BYTES
            for kind, (_, max_bytes) in self.kinds.items()
        )
        return max([MAX_PACKET_BYTES, *commands])

    def subscribe(self, client: Any) -> None:
        for kind in self.kinds:  # a clean session: subscribed again on every connection
            client.subscribe(self.topics.of(f"cmd/{kind}"), qos=1)

    def unsubscribe(self, client: Any) -> None:
        for kind in self.kinds:
            client.unsubscribe(self.topics.of(f"cmd/{kind}"))

    def dispatch(self, message: mqtt.MQTTMessage) -> None:
        """A message on ``cmd/<kind>`` (paho's thread): handed to the loop, or refused unparsed."""
        kind = message.topic.removeprefix(self.topics.of("cmd/"))
        handler, max_bytes = self.kinds.get(kind, (None, 0))
        loop = self.loop
        if handler is None or loop is None:
            return
        payload = bytes(message.payload)
        with contextlib.suppress(RuntimeError):  # the loop closed meanwhile
            if len(payload) > max_bytes:
                why = f"{len(payload)} bytes, more than the {max_bytes} a {kind} command may have"
                loop.call_soon_threadsafe(self._refuse, message.topic, payload, why)
                return
            loop.call_soon_threadsafe(self._handle, message.topic, handler, payload, message.retain)

    def _handle(self, topic: str, handler: Handler, payload: bytes, retained: bool) -> None:
        if len(self._handling) >= MAX_HANDLING:
            why = f"{MAX_HANDLING} commands are being handled already: send it again later"
            self._refuse(topic, payload, why)
            return
        task = asyncio.ensure_future(handler(payload, retained=retained))
        self._handling.add(task)  # a reference until done: the loop keeps only weak ones
        task.add_done_callback(self._handling.discard)

    def _refuse(self, topic: str, payload: bytes, why: str) -> None:
        """On the loop: one ERROR line, a ``fault`` event, the answer where the bytes name an id."""
        request_id = cheap_request_id(payload)
        log.error("command refused unread", topic=topic, reason=why, request_id=request_id)
        details = {"topic": topic, "bytes": len(payload), "reason": why, "request_id": request_id}
        self.events(Event("fault", "command refused unread", details))
        if request_id is not None and self.reply is not None:
            answer = {"request_id": request_id, "ok": False, "result": "refused", "reason": why}
            self.reply(request_id, answer)
