"""What the fleet's broker says about the machines, read until it is all there.

``compd model rollout`` (and its ``--pending`` and ``--online``) and ``compd
fleet list`` subscribe to the machines' retained births, deaths and desired
records. A broker sends a subscription's retained messages after its SUBACK,
and at most its in-flight window at a time (mosquitto: 20 at QoS 1), so the
SUBACK says nothing about whether they have all arrived: with 51 retained,
28 had come when a second SUBACK did. So :func:`connected` then publishes a
marker, ``{"schema": "compd.marker/1"}`` on ``<prefix>/<marker>/desired`` (not retained;
the roll-out user may write ``<prefix>/+/desired``, and no daemon reads
another machine's topics), and waits until the marker comes back: the broker
queues it behind every retained message it owes this client, and delivers
its queue in order. A marker that does not come back within the timeout is
an error (the broker dropped part of the queue, or refused the marker),
never a fleet that looks smaller than it is.
"""

from __future__ import annotations

import contextlib
import json
import threading
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import paho.mqtt.client as mqtt

from compd.errors import CompdError
from compd.service.config.fleetdoc import TelemetryDoc
from compd.service.fleet.mqttlink import broker as broker_of
from compd.service.fleet.mqttlink import mqtt_client
from compd.service.fleet.remoteload import DESIRED

#: The marker's payload names it (JSON, as every message under the prefix; no desired record).
MARKER_SCHEMA = "compd.marker/1"
#: The kinds of topic a listener reads of each machine.
KINDS = ("birth", "death", "event", "reply/#", DESIRED)


class Listener:
    """What the broker says about the machines: retained birth and death, replies, events."""

    def __init__(self, prefix: str, machines: list[str], kinds: tuple[str, ...] = KINDS) -> None:
        self.prefix = prefix
        self.machines = machines
        self.kinds = kinds
        self.lock = threading.Lock()
        self.heard: dict[tuple[str, str], list[dict[str, Any]]] = {}
        self.subscribed = threading.Event()
        self.refused = ""
        #: A topic level no machine has: the marker's (see the module's docstring).
        self.marker = f"_marker-{uuid.uuid4().hex}"
        #: Set when the marker came back (every retained message before it has arrived).
        self.complete = threading.Event()
        self.marker_refused = ""
        self.marker_mid: int | None = None

    def topics(self) -> list[tuple[str, int]]:
        """The machines' topics of each kind, and the marker's (its own unless ``+`` covers it)."""
        topics = [(f"{self.prefix}/{m}/{kind}", 1) for m in self.machines for kind in self.kinds]
        if "+" not in self.machines or DESIRED not in self.kinds:
            topics.append((self.marker_topic, 1))
        return topics

    @property
    def marker_topic(self) -> str:
        return f"{self.prefix}/{self.marker}/{DESIRED}"

    def on_connect(self, client: Any, userdata: Any, flags: Any, reason: Any, props: Any) -> None:
        if reason.is_failure:  # a wrong password, an unknown user: say so at once
            self.refused = str(reason)
            self.subscribed.set()
        else:
            client.subscribe(self.topics())

    def on_subscribe(self, *args: Any) -> None:
        self.subscribed.set()

    def on_publish(self, client: Any, userdata: Any, mid: int, reason: Any, props: Any) -> None:
        """The marker's PUBACK: an MQTT 5 broker says here if the ACL refused it."""
        if mid == self.marker_mid and getattr(reason, "is_failure", False):
            self.marker_refused = str(reason)
            self.complete.set()

    def on_message(self, client: Any, userdata: Any, message: Any) -> None:
        parts = message.topic.removeprefix(f"{self.prefix}/").split("/")
        if parts[0] == self.marker:
            self.complete.set()
            return
        if parts[0].startswith("_marker-"):
            return  # another tool's marker, on a topic this one reads too
        try:
            payload = json.loads(message.payload)
        except (ValueError, RecursionError):  # not a reply compd sent: nesting too deep to parse
            return
        if not isinstance(payload, dict) or len(parts) < 2:
            return
        kind = "reply" if parts[1:2] == ["reply"] else parts[1]
        with self.lock:
            self.heard.setdefault((parts[0], kind), []).append(payload)

    def of(self, machine: str, kind: str) -> list[dict[str, Any]]:
        with self.lock:
            return list(self.heard.get((machine, kind), []))

    def machines_heard(self, kind: str) -> list[str]:
        """The machines a message of ``kind`` was heard from."""
        with self.lock:
            return [m for m, k in self.heard if k == kind]


@contextlib.contextmanager
def connected(
    section: TelemetryDoc, base_dir: Path, listener: Listener, timeout_s: float
) -> Iterator[mqtt.Client]:
    """A client of the broker, logged in, ``listener`` subscribed and every retained message heard.

    Disconnected afterwards. Raises CompdError if the broker cannot be
    reached, refuses the login or does not hand over its retained messages
    (the marker, :mod:`compd.cli.fleetstate`) within ``timeout_s``.
    """
    broker = broker_of(section, base_dir, f"compd-rollout-{uuid.uuid4().hex[:12]}")
    client = mqtt_client(broker)
    client.on_connect = listener.on_connect
    client.on_subscribe = listener.on_subscribe
    client.on_message = listener.on_message
    client.on_publish = listener.on_publish
    try:
        client.connect(broker.host, broker.port, broker.keepalive_s)
    except (OSError, ValueError) as exc:
        raise CompdError(
            f"cannot connect to the broker {broker.host}:{broker.port} ({exc})"
        ) from exc
    client.loop_start()
    try:
        if not listener.subscribed.wait(timeout_s) or listener.refused:
            why = listener.refused or f"no answer in {timeout_s:g} s"
            raise CompdError(f"the broker {broker.host}:{broker.port} refused the login ({why})")
        marker = json.dumps({"schema": MARKER_SCHEMA, "kind": "marker"})
        listener.marker_mid = client.publish(listener.marker_topic, marker, qos=1).mid
        if not listener.complete.wait(timeout_s):
            raise CompdError(
                f"the broker {broker.host}:{broker.port} did not hand over its retained messages "
                f"in {timeout_s:g} s: the marker published to {listener.marker_topic} after them "
                "did not come back (a queue that drops messages: raise mosquitto's "
                "max_queued_messages, default 1000, above three per machine; or a slow broker: "
                "a longer --timeout-s)"
            )
        if listener.marker_refused:
            raise CompdError(
                f"the broker {broker.host}:{broker.port} refused this user's message to "
                f"{listener.marker_topic} ({listener.marker_refused}): reading the fleet's "
                f"retained state and rolling out need write on {section.topic_prefix}/+/{DESIRED}, "
                "as the roll-out user has (the ACL: deploy/README.md, 'The MQTT broker')"
            )
        yield client
    finally:
        client.disconnect()
        client.loop_stop()


def presence(listener: Listener, machine: str) -> str:
    """Sparkplug's rule: online while the newest birth's session is newer than the newest death's.

    A death counts only for the birth of the same instance (a daemon standing
    by, compd.service.fleet.claim, leaves its will on the same topic).
    """
    births, deaths = listener.of(machine, "birth"), listener.of(machine, "death")
    if not births:
        return "never seen"
    birth = births[-1]
    for death in reversed(deaths):
        ids = {(p.get("instance") or {}).get("id") for p in (birth, death)}
        if len(ids) == 1 or None in ids:
            if death.get("session", 0) >= birth.get("session", 0):
                return f"offline ({death.get('reason', '?')})"
            break
    return "online"
