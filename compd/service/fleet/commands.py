"""The commands a daemon's telemetry takes: ``<prefix>/<machine_id>/cmd/<kind>``, bounded, on the loop.

With ``accept_models: true`` (never by default) the daemon subscribes to
``cmd/<kind>`` for each kind registered (:meth:`Commands.listen`;
:mod:`compd.service.fleet.remoteload` is the one command, a model rolled out to
the fleet) while it publishes, and answers on ``reply/<request_id>``. A
command's payload is bounded (the connection's MQTT 5 Maximum Packet Size:
the broker drops a larger message before sending it; and its length is
checked again here) and handed from paho's thread to the event loop with its
retain flag, never acted on in paho's thread.
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

log = structlog.get_logger("compd.service.fleet.telemetry")

#: A command's handler: ``await handler(payload, retained=flag)`` (the broker's retain flag).
Handler = Callable[..., Awaitable[None]]

#: A command's packet beyond its payload, at most: fixed header, topic, packet id, properties.
PACKET_OVERHEAD_BYTES = 1024
#: The largest packet taken without commands: the acknowledgements of what is published.
MAX_PACKET_BYTES = 64 * 1024


class Commands:
    """``cmd/<kind>`` -> (handler, largest payload in bytes); dispatched onto the event loop."""

    def __init__(self, topics: Topics, events: EventSink) -> None:
        self.topics = topics
        self.events = events
        self.kinds: dict[str, tuple[Handler, int]] = {}
        self.loop: asyncio.AbstractEventLoop | None = None
        self._handling: set[asyncio.Task[None]] = set()

    def listen(self, kind: str, handler: Handler, *, max_bytes: int) -> None:
        """Act on ``cmd/<kind>``: ``await handler(payload, retained=...)`` on the loop.

        A message whose packet would exceed ``max_bytes`` and
        :data:`PACKET_OVERHEAD_BYTES` is dropped by the broker
        (:attr:`max_packet_bytes`); a payload over ``max_bytes`` that arrives
        all the same is dropped unread, logged and told as a ``fault`` event
        (there is no request id to answer to without reading it).
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
        """A message on ``cmd/<kind>`` (paho's thread): handed to the loop, or refused if too large."""
        kind = message.topic.removeprefix(self.topics.of("cmd/"))
        handler, max_bytes = self.kinds.get(kind, (None, 0))
        if handler is None or self.loop is None:
            return
        if len(message.payload) > max_bytes:
            log.error("command refused: too large", topic=message.topic, bytes=len(message.payload))
            details = {"topic": message.topic, "bytes": len(message.payload), "max": max_bytes}
            self.events(Event("fault", "command refused: too large", details))
            return
        with contextlib.suppress(RuntimeError):  # the loop closed meanwhile
            payload = bytes(message.payload)
            self.loop.call_soon_threadsafe(self._handle, handler, payload, message.retain)

    def _handle(self, handler: Handler, payload: bytes, retained: bool) -> None:
        task = asyncio.ensure_future(handler(payload, retained=retained))
        self._handling.add(task)  # a reference until done: the loop keeps only weak ones
        task.add_done_callback(self._handling.discard)
