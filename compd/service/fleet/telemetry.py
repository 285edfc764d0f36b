"""MQTT telemetry: each machine's birth, status, events and death, published beside the loop.

A fleet's dashboard wants every machine's inputs, model output, offsets and
status word without asking each daemon's control socket. This module
publishes them to an MQTT broker (paho-mqtt 2.x, its own network thread)
under ``<prefix>/<machine_id>/``:

``birth`` (retained)
    on each connection: who is publishing (machine, compd version, model,
    signals and their units, axes, period) and the ``session`` number;
``status``
    every ``every_ticks`` ticks: inputs with health, model outputs, offsets
    the stage gives and those the PLC acknowledged, status word, counters;
``event``
    fault episodes (start, end), driver reconnects, model loads, switches,
    blends and failures, as they happen (:class:`compd.faultlog.Event`);
``death`` (retained)
    ``reason: stopped`` on a clean stop (with the final counters), else the
    broker's last will, ``reason: connection lost``, when the daemon dies or
    its network goes.

Payloads are JSON objects with ``schema: compd.telemetry/1``. Birth and
death follow Sparkplug B's rule without its protobuf payload: both carry the
``session`` (Sparkplug's bdSeq), and a machine is online while its retained
birth's session is newer than its retained death's. The session grows with
every connection, so the will registered for a connection names that
connection's session.

Publishing never delays a tick: the tick appends a snapshot (references to
the tick's fresh record, no serialisation) to a bounded deque that drops the
oldest entry and counts it when full; an asyncio task serialises and hands
messages to paho while the broker is connected; paho's thread does the
network I/O. A broker that goes away is a fault of the telemetry, logged once
(:class:`compd.faultlog.FaultLog`) and counted, never of the compensation:
the queue fills and drops its oldest entries, paho reconnects with backoff,
and the birth (then the queued backlog) is published again.

Before it publishes, a daemon reads its machine's retained birth and death,
and stands by while another live daemon publishes as its ``machine_id``
(:mod:`compd.service.fleet.claim`). Payloads: :mod:`~compd.service.fleet.payloads`;
commands (``accept_models: true``, answered on ``reply/<request_id>`` by
:meth:`Telemetry.reply`): :mod:`~compd.service.fleet.commands`.
"""

from __future__ import annotations

import asyncio
import contextlib
import threading
import time
from collections import deque
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any

import paho.mqtt.client as mqtt
import structlog
from paho.mqtt.enums import MQTTErrorCode
from paho.mqtt.subscribeoptions import SubscribeOptions

from compd.faultlog import Event, FaultLog
from compd.service.fleet.claim import Claim, Instance, where
from compd.service.fleet.commands import Commands, Handler
from compd.service.fleet.jsonwire import dumps
from compd.service.fleet.mqttlink import Broker, Topics, connect_properties, mqtt_client
from compd.service.fleet.payloads import DESIRED_KEYS, Payloads
from compd.service.fleet.wirecheck import record_or_none
from compd.service.loop.compensator import TickRecord
from compd.service.loop.snapshot import TickSnapshot

log = structlog.get_logger("compd.service.fleet.telemetry")


#: Messages handed to paho and not yet acknowledged, at most: beyond, the rest wait in the
#: bounded queue (where the oldest are dropped), not in paho's (which would grow without bound).
MAX_UNACKNOWLEDGED = 100
#: Longest a clean stop waits for the queue to drain and the death message's acknowledgement (s).
STOP_TIMEOUT_S = 5.0
#: MQTT 5's reason code when the broker drops a connection for another with the same client id.
SESSION_TAKEN_OVER = 0x8E
#: The largest birth or death of this machine_id read (another daemon's): a few kB in practice.
MAX_OWN_BYTES = 256 * 1024


@dataclass
class TelemetryCounters:
    """What the telemetry did: messages handed to paho, acknowledged, dropped; connections."""

    queued: int = 0
    published: int = 0
    acknowledged: int = 0
    #: Snapshots and events dropped: the oldest of a full queue, or refused by paho.
    dropped: int = 0
    connections: int = 0
    connected: bool = False


class Telemetry:
    """One machine's MQTT publisher; :meth:`start`, then :meth:`tick` and :meth:`event`, then :meth:`stop`.

    ``identity()`` gives the birth's description of the machine (model,
    signals, axes), read when a birth is published; ``wall()`` the time
    stamped on events (the service's clock, virtual in a simulation).
    """

    def __init__(
        self,
        broker: Broker,
        topics: Topics,
        *,
        qos: int = 1,
        every_ticks: int = 1,
        queue_size: int = 1000,
        identity: Callable[[], dict[str, Any]] = dict,
        wall: Callable[[], float] = time.time,
        instance: Instance | None = None,
        probes: Callable[[], dict[str, Any] | None] = lambda: None,
    ) -> None:
        self.broker = broker
        self.topics = topics
        self.qos = qos
        self.every_ticks = every_ticks
        self.wall = wall
        #: Per probed axis, what the probes say now (``ProbeLearning.status``'s axes); None: no probes.
        self.probes = probes
        self.counters = TelemetryCounters()
        #: This process, as its birth, death and will name it (:mod:`compd.service.fleet.claim`).
        self.instance = instance or Instance.this_process()
        self._claim = Claim(self.instance)
        #: Connected, and no other live daemon publishes as this machine_id: publishing.
        self._active = False
        #: The SUBACK after which the retained birth and death of this machine_id have been heard.
        self._check_mid: int | None = None
        #: The other live daemon this one stands by for (its birth's ``instance``), if any.
        self.rival: dict[str, Any] | None = None
        self.payloads = Payloads(
            topics, self.instance, every_ticks=every_ticks, identity=identity, wall=wall
        )
        self._statuses: deque[
            tuple[TickRecord, dict[str, int], str | None, dict[str, Any] | None]
        ] = deque(maxlen=queue_size)
        self._events: deque[tuple[float, Event]] = deque(maxlen=queue_size)
        self._birth_due = False
        self._waiting_for_acks = False
        self._fault = FaultLog(log, broker=f"{broker.host}:{broker.port}")
        self._fault.sink = self.event  # the broker's own faults are events, published on return
        self._duplicate = FaultLog(log, machine_id=topics.machine_id)
        self._duplicate.sink = self.event
        self._client = self._make_client()
        self._wake: asyncio.Event | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._loop_thread = 0
        self._task: asyncio.Task[None] | None = None
        self.commands = Commands(topics, self.event, self.reply)
        #: Takes the roll-out's desired record heard at connecting (``accept_models``), if set.
        self._desired_handler: Callable[[bytes], Awaitable[None]] | None = None
        #: The retained desired record heard at this connection, until this daemon publishes.
        self._desired_due: tuple[bytes, Any] | None = None
        self._taking: set[asyncio.Task[None]] = set()

    @property
    def publishing(self) -> bool:
        """Connected, and no other live daemon publishes as this machine_id (module mqttclaim)."""
        return self._active

    @property
    def fault_active(self) -> bool:
        """The broker is away (unreachable, refusing, or the connection lost) and has not come back."""
        return self._fault.active

    def _make_client(self) -> mqtt.Client:
        client = mqtt_client(self.broker)
        client.max_queued_messages_set(MAX_UNACKNOWLEDGED + 10)  # + the death, at stop
        client.on_pre_connect = self._on_pre_connect
        client.on_connect = self._on_connect
        client.on_subscribe = self._on_subscribe
        client.on_connect_fail = self._on_connect_fail
        client.on_disconnect = self._on_disconnect
        client.on_publish = self._on_publish
        client.on_message = self._on_message
        return client

    # -- the loop's side --------------------------------------------------------------------

    def start(self) -> None:
        """Connect in the background (paho's thread) and start the publishing task; never blocks."""
        self._loop = self.commands.loop = asyncio.get_running_loop()
        self._loop_thread = threading.get_ident()
        self._wake = asyncio.Event()
        self._client.connect_async(
            self.broker.host,
            self.broker.port,
            self.broker.keepalive_s,
            clean_start=True,
            properties=connect_properties(self.max_packet_bytes),
        )
        self._client.loop_start()
        self._task = self._loop.create_task(self._publish_queued(), name="compd-telemetry")

    name = "telemetry"
    _ticks = 0  # the last tick's count: the death message says it

    async def begin(self) -> None:
        """Connect in the background: a broker away delays nothing."""
        self.start()

    async def end(self, *, killed: bool) -> None:
        """The death message and a clean disconnect (not when killed: the broker sends the will)."""
        if not killed:
            await self.stop(ticks=self._ticks)

    def on_tick(self, snapshot: TickSnapshot) -> None:
        """The loop's subscriber: every ``every_ticks`` ticks, a status message queued."""
        self._ticks = snapshot.ticks
        if snapshot.ticks % self.every_ticks == 0:
            model = None if snapshot.model is None else snapshot.model.name
            self.tick(snapshot.record, dict(snapshot.counters), model, self.probes())

    def tick(
        self,
        record: TickRecord,
        counters: dict[str, int],
        model: str | None,
        probes: dict[str, Any] | None = None,
    ) -> None:
        """Queue the tick's status (cheap: no serialisation here); the oldest goes when full."""
        queue = self._statuses
        if len(queue) == queue.maxlen:
            self.counters.dropped += 1
        queue.append((record, counters, model, probes))
        self.counters.queued += 1
        self._notify()

    def event(self, event: Event) -> None:
        """Queue an event (any thread); the oldest goes when full."""
        queue = self._events
        if len(queue) == queue.maxlen:
            self.counters.dropped += 1
        queue.append((self.wall(), event))
        self.counters.queued += 1
        if event.kind == "model_switched":
            self._birth_due = True  # the retained birth names the running model
        self._notify()

    def _notify(self) -> None:
        if self._wake is None or self._loop is None:
            return
        if threading.get_ident() == self._loop_thread:
            self._wake.set()
        elif not self._loop.is_closed():
            self._loop.call_soon_threadsafe(self._wake.set)

    async def _publish_queued(self) -> None:
        """Hand queued messages to paho while connected: the birth first, then events, then statuses."""
        assert self._wake is not None
        while True:
            await self._wake.wait()
            self._wake.clear()
            sent = 0
            while self._active and self.counters.connected:
                self._waiting_for_acks = self._unacknowledged >= MAX_UNACKNOWLEDGED
                if self._waiting_for_acks:
                    break  # _on_publish wakes this task again
                if self._birth_due:
                    self._birth_due = False
                    birth = self.payloads.birth(self.event) | {"commands": list(self.listening)}
                    self._publish("birth", birth, retain=True)
                elif self._events:
                    at_s, event = self._events.popleft()
                    self._publish("event", self.payloads.event(at_s, event))
                elif self._statuses:
                    record, counters, model, probes = self._statuses.popleft()
                    status = self.payloads.status(
                        record, counters, model, self.counters.dropped, probes=probes
                    )
                    self._publish("status", status)
                else:
                    break
                sent += 1
                if sent % 50 == 0:
                    await asyncio.sleep(0)  # a backlog never holds up a tick

    @property
    def _unacknowledged(self) -> int:
        return self.counters.published - self.counters.acknowledged

    def _publish(self, kind: str, payload: dict[str, Any], *, retain: bool = False) -> bool:
        try:
            data = dumps(payload)
        except ValueError as exc:  # a NaN in an event's details: that message only is lost
            log.error("telemetry message not serialisable", kind=kind, error=str(exc))
            self.counters.dropped += 1
            return False
        info = self._client.publish(self.topics.of(kind), data, self.qos, retain)
        if info.rc != MQTTErrorCode.MQTT_ERR_SUCCESS:
            self.counters.dropped += 1  # lost the connection meanwhile, or paho's queue is full
            return False
        self.counters.published += 1
        return True

    async def stop(self, *, ticks: int | None = None) -> None:
        """Publish what is queued and the retained death (``stopped``), then disconnect; bounded in time."""
        if self._loop is None:
            return
        deadline = time.monotonic() + STOP_TIMEOUT_S
        while self._active and (self._events or self._statuses or self._birth_due):
            if time.monotonic() > deadline:
                break
            self._notify()
            await asyncio.sleep(0.01)
        if (
            self._active
        ):  # a daemon standing by has no birth to end (its will goes with the disconnect)
            death = self.payloads.death("stopped", ticks=ticks, telemetry=self.status_counters())
            info = self._client.publish(self.topics.of("death"), dumps(death), self.qos, True)
            self.counters.published += 1
            remaining_s = max(0.1, deadline - time.monotonic())
            await asyncio.to_thread(_wait_published, info, remaining_s)
        self._client.disconnect()
        await asyncio.to_thread(self._client.loop_stop)
        if self._task is not None:
            self._task.cancel()
        log.info("telemetry stopped", **self.status_counters())

    def listen(self, kind: str, handler: Handler, *, max_bytes: int) -> None:
        """Act on ``cmd/<kind>`` while publishing (before :meth:`start`; :mod:`~compd.service.fleet.commands`)."""
        self.commands.listen(kind, handler, max_bytes=max_bytes)

    def take_desired(self, handler: Callable[[bytes], Awaitable[None]]) -> None:
        """Hand the retained ``desired`` record heard at connecting to ``handler`` (on the loop).

        Only while publishing, and only if it names another model than the
        running one: a machine that was away takes what the roll-out left
        (:meth:`compd.service.fleet.remoteload.RemoteLoads.take_desired`). A record
        that arrives live is not handed over: the roll-out's command follows it.
        """
        self._desired_handler = handler

    @property
    def max_packet_bytes(self) -> int:
        """The Maximum Packet Size told to the broker (:class:`~compd.service.fleet.commands.Commands`)."""
        return self.commands.max_packet_bytes

    @property
    def listening(self) -> tuple[str, ...]:
        """The command kinds this daemon acts on (none unless the config says ``accept_models``)."""
        return tuple(self.commands.kinds)

    def reply(self, request_id: str, payload: dict[str, Any]) -> bool:
        """Publish the answer to a command on ``reply/<request_id>`` (the loop's thread; QoS 1)."""
        return self._publish(f"reply/{request_id}", self.payloads.header("reply") | payload)

    def status_counters(self) -> dict[str, Any]:
        """For ``compd status`` and the death message."""
        c = self.counters
        return {
            "connected": c.connected,
            "published": c.published,
            "acknowledged": c.acknowledged,
            "dropped": c.dropped,
            "connections": c.connections,
            "stands_by_for": None if self.rival is None else where(self.rival),
        }

    # -- paho's thread --------------------------------------------------------------------------

    def _on_pre_connect(self, client: Any, userdata: Any) -> None:
        """Each connection's will, stamped now: the broker sends it unstamped, when it notices."""
        will = dumps(self.payloads.will())
        client.will_set(self.topics.of("death"), will, self.qos, retain=True)

    def _on_connect(self, client: Any, userdata: Any, flags: Any, reason: Any, props: Any) -> None:
        if reason.is_failure:
            self._fault.failed("telemetry broker refused the connection", reason=str(reason))
            return
        self.counters.connections += 1
        self.counters.connected = True
        self._active = False
        # Who else publishes as this machine_id: the retained birth and death come after the first
        # SUBACK and before the second (the broker answers a client's packets in order).
        own = SubscribeOptions(qos=1, noLocal=True)
        mine = [(self.topics.of(kind), own) for kind in ("birth", "death", "desired")]
        client.subscribe(mine)
        quiet = SubscribeOptions(qos=1, noLocal=True, retainHandling=2)
        self._check_mid = client.subscribe(self.topics.of("death"), options=quiet)[1]
        if self.counters.connections == 1 and not self._fault.active:
            log.info("telemetry connected", broker=f"{self.broker.host}:{self.broker.port}")
        self._fault.cleared("telemetry broker connected again", also="reconnected")

    def _on_subscribe(self, client: Any, userdata: Any, mid: int, codes: Any, props: Any) -> None:
        if mid == self._check_mid:
            self._check_mid = None
            self._decide(client, publishing=False)

    def _decide(self, client: Any, *, publishing: bool) -> None:
        """Publish, or stand by for another live daemon with this machine_id (module mqttclaim)."""
        rival = self._claim.rival(publishing=publishing)
        if rival is not None:
            self._stand_by(client, rival)
        elif not self._active:
            self._active = True
            self._birth_due = True
            self.commands.subscribe(client)
            self._hand_desired()
            if self.rival is not None:
                self.rival = None
                self._duplicate.cleared("telemetry publishes: the other daemon is gone")
            self._notify()

    def _stand_by(self, client: Any, rival: dict[str, Any]) -> None:
        instance = rival.get("instance") or {}
        if self._active:
            self._active = False
            self.commands.unsubscribe(client)
        self.rival = instance
        self._duplicate.failed(
            f"telemetry stands by: {where(instance)} already publishes as this machine_id",
            other_host=instance.get("host"),
            other_pid=instance.get("pid"),
            fix="give each daemon its own telemetry.machine_id, or stop the other one",
        )

    def _heard_own(self, client: Any, kind: str, message: mqtt.MQTTMessage) -> None:
        """Another daemon's birth or death on this machine_id's topics (module mqttclaim)."""
        payload = record_or_none(bytes(message.payload), max_bytes=MAX_OWN_BYTES)
        if not isinstance(payload, dict) or not self._claim.heard(kind, payload):
            return
        if self._check_mid is not None or not self.counters.connected:
            return  # decided when the check's SUBACK comes
        if not self._active:
            self._decide(client, publishing=False)
        elif kind == "birth" and not message.retain:
            self._decide(client, publishing=True)
            if self._active:  # this one started first and keeps on: its birth is the retained one
                other = payload.get("instance") or {}
                log.error(
                    "another daemon published as this machine_id; it started later and stands by",
                    machine_id=self.topics.machine_id,
                    other=where(other),
                    fix="give each daemon its own telemetry.machine_id, or stop the other one",
                )
                self._birth_due = True
                self._notify()

    def _on_connect_fail(self, client: Any, userdata: Any) -> None:
        self._fault.failed("telemetry broker unreachable")

    def _on_disconnect(
        self, client: Any, userdata: Any, flags: Any, reason: Any, props: Any
    ) -> None:
        self.counters.connected = self._active = False
        if reason.value == SESSION_TAKEN_OVER:
            self._fault.failed(
                "telemetry broker connection lost: another client connected with this client id",
                client_id=self.broker.client_id,
                fix="give each daemon its own telemetry.client_id (or leave it out) and machine_id",
            )
        elif reason.is_failure:
            self._fault.failed("telemetry broker connection lost", reason=str(reason))
        self.payloads.session += (
            1  # the next connection is a new session (its will: _on_pre_connect)
        )

    def _on_message(self, client: Any, userdata: Any, message: mqtt.MQTTMessage) -> None:
        for own in ("birth", "death"):
            if message.topic == self.topics.of(own):
                self._heard_own(client, own, message)
                return
        if message.topic == self.topics.of("desired"):
            self._heard_desired(bytes(message.payload), retained=bool(message.retain))
            return
        self.commands.dispatch(message)

    def _heard_desired(self, data: bytes, *, retained: bool) -> None:
        """The roll-out's record of the model this machine should run: said in the next birth.

        Heard from the retained store (at connecting), it is also taken (:meth:`take_desired`).
        Bounded as the model roll-out's command is (size, then depth, before
        it is parsed), and parsed once here: the loop gets the bytes and its sha256.
        """
        record = record_or_none(data, max_bytes=self.commands.max_packet_bytes) if data else None
        if data and not isinstance(record, dict):
            log.error(
                "desired model record ignored: too large, nested too deep or not a JSON object"
            )
            return
        self.payloads.desired = None if record is None else {k: record.get(k) for k in DESIRED_KEYS}
        due = retained and record is not None
        self._desired_due = (data, record.get("sha256")) if due and record is not None else None
        if self._active:
            self._hand_desired()
            self._birth_due = True
            self._notify()

    def _hand_desired(self) -> None:
        """The desired record heard at connecting, to the loop's :meth:`_take_desired` (once)."""
        due, self._desired_due = self._desired_due, None
        if due is None or self._desired_handler is None or self._loop is None:
            return
        with contextlib.suppress(RuntimeError):  # the loop closed meanwhile
            self._loop.call_soon_threadsafe(self._take_desired, *due)

    def _take_desired(self, data: bytes, sha256: Any) -> None:
        """On the loop: hand the record over if it names another model than the running one."""
        running = (self.payloads.identity().get("model") or {}).get("sha256")
        if self._desired_handler is None or sha256 in (None, running):
            return
        task = asyncio.ensure_future(self._desired_handler(data))
        self._taking.add(task)  # a reference until done: the loop keeps only weak ones
        task.add_done_callback(self._taking.discard)

    def _on_publish(self, client: Any, userdata: Any, mid: int, reason: Any, props: Any) -> None:
        self.counters.acknowledged += 1
        if self._waiting_for_acks and self._unacknowledged < MAX_UNACKNOWLEDGED // 2:
            self._waiting_for_acks = False
            self._notify()


def _wait_published(info: mqtt.MQTTMessageInfo, timeout_s: float) -> None:
    try:
        info.wait_for_publish(timeout_s)
    except (RuntimeError, ValueError) as exc:  # the connection went meanwhile
        log.warning("telemetry death message not confirmed", error=str(exc))
