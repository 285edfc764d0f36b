"""A rolled-out model is taken once, as sent, and only fresh; an oversize command never reaches the daemon.

Through a real mosquitto: a retained command handed out again at a restart, a
replayed request (live and after a restart), a payload far over the bound
(dropped by the broker: the MQTT 5 Maximum Packet Size the daemon connects
with). Without a broker: stale, undated and future-dated requests, and the
seen-ids file's bounds.
"""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import Callable
from pathlib import Path

import paho.mqtt.client as mqtt
import pytest
from paho.mqtt.enums import CallbackAPIVersion

from compd.service.fleet.mqttlink import Broker, Topics
from compd.service.fleet.remoteload import MAX_PAYLOAD_BYTES, RemoteLoads
from compd.service.fleet.seenrequests import WINDOW_S, SeenRequests
from compd.service.fleet.telemetry import Telemetry
from tests.mosquitto import WAIT_S, Mosquitto, Subscriber, mosquitto_binary
from tests.service.test_remoteload import ACCEPTED, Daemon, request

TOPIC = "compd/m/cmd/model_load"
NOW = 1_790_000_000.0
needs_mosquitto = pytest.mark.skipif(
    mosquitto_binary() is None, reason="mosquitto is not installed: run .ci/install-system-packages"
)


async def until(predicate: Callable[[], bool], what: str) -> None:
    """Wait on the event loop (real time, bounded by WAIT_S) until ``predicate()``."""
    deadline = time.monotonic() + WAIT_S
    while not predicate():
        assert time.monotonic() < deadline, f"never {what}"
        await asyncio.sleep(0.01)


class Machine:
    """A daemon's command side on a real broker: Telemetry and RemoteLoads, its seen ids in ``state``."""

    def __init__(self, broker: Mosquitto, state: Path, daemon: Daemon) -> None:
        self.broker = broker
        self.seen_file = state / "model_requests.json"
        self.daemon = daemon
        self.sessions = 0

    async def session(self, sub: Subscriber, act: Callable[[], None], done: Callable[[], bool]):
        """Start (a restart: new objects, the same state), wait to be born, ``act()``, wait until ``done()``, stop."""
        telemetry = Telemetry(
            Broker("127.0.0.1", self.broker.port, "compd-m"), Topics("compd", "m")
        )
        seen = SeenRequests(self.seen_file)
        remote = RemoteLoads(self.daemon.load, telemetry.reply, telemetry.event, seen=seen)
        telemetry.listen("model_load", remote.handle, max_bytes=MAX_PAYLOAD_BYTES)
        telemetry.start()
        self.sessions += 1
        await until(lambda: len(sub.of("birth")) == self.sessions, "born")
        act()
        await until(done, "answered")
        await telemetry.stop()


def sender(port: int) -> mqtt.Client:
    """The roll-out user's client: publishes commands."""
    client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id="rollout")
    client.connect("127.0.0.1", port)
    client.loop_start()
    return client


def replies(sub: Subscriber) -> list[tuple[str, str]]:
    """Each reply heard: its result and reason, in order."""
    return [(r["result"], r.get("reason", "")) for r in sub.of("reply")]


@needs_mosquitto
def test_a_retained_command_is_refused_at_every_restart_and_the_reply_says_so(tmp_path: Path):
    """Published retained: loaded once as it arrives; a restart gets it from the retained store and refuses it."""
    broker = Mosquitto(tmp_path).start()
    daemon = Daemon(ACCEPTED)
    machine = Machine(broker, tmp_path / "state", daemon)
    out = sender(broker.port)
    payload = request(request_id="retained-1")
    try:
        with Subscriber(broker.port, "compd/m/#") as sub:

            def publish() -> None:
                out.publish(TOPIC, payload, qos=1, retain=True).wait_for_publish(WAIT_S)

            for n, act in ((1, publish), (2, lambda: None), (3, lambda: None)):
                asyncio.run(machine.session(sub, act, lambda n=n: len(sub.of("reply")) == n))
    finally:
        out.loop_stop()
        broker.stop()
    assert len(daemon.loads) == 1
    (first, _), *again = replies(sub)
    assert first == "accepted"
    assert [result for result, _ in again] == ["refused", "refused"]
    assert all("retained" in reason and "mosquitto_pub -r -n" in reason for _, reason in again)


@needs_mosquitto
def test_a_replayed_request_is_refused_live_and_after_a_restart(tmp_path: Path):
    """The same request_id and bytes again: refused as a replay, also by a restarted daemon (ids kept in the state)."""
    broker = Mosquitto(tmp_path).start()
    daemon = Daemon(ACCEPTED)
    machine = Machine(broker, tmp_path / "state", daemon)
    out = sender(broker.port)
    payload = request(request_id="replay-1")
    try:
        with Subscriber(broker.port, "compd/m/#") as sub:

            def publish(times: int) -> Callable[[], None]:
                def act() -> None:
                    for _ in range(times):
                        out.publish(TOPIC, payload, qos=1).wait_for_publish(WAIT_S)

                return act

            asyncio.run(machine.session(sub, publish(2), lambda: len(sub.of("reply")) == 2))
            asyncio.run(machine.session(sub, publish(1), lambda: len(sub.of("reply")) == 3))
    finally:
        out.loop_stop()
        broker.stop()
    assert len(daemon.loads) == 1
    results = sorted(replies(sub))  # the two of the first session in either order
    assert [r for r, _ in results] == ["accepted", "refused", "refused"]
    assert all("replay-1 was taken before: a replay" in reason for _, reason in results[1:])


@needs_mosquitto
def test_a_command_far_over_the_bound_is_dropped_by_the_broker_never_received(tmp_path: Path):
    """Four times the payload bound: the broker drops it (the daemon's Maximum Packet Size); the next arrives."""
    broker = Mosquitto(tmp_path).start()
    handled: list[bytes] = []

    async def handler(payload: bytes, *, retained: bool = False) -> None:
        handled.append(payload)

    async def run(sub: Subscriber) -> None:
        telemetry = Telemetry(Broker("127.0.0.1", broker.port, "compd-m"), Topics("compd", "m"))
        telemetry.listen("model_load", handler, max_bytes=MAX_PAYLOAD_BYTES)
        telemetry.start()
        await until(lambda: bool(sub.of("birth")), "born")
        huge = out.publish(TOPIC, b"x" * (4 * MAX_PAYLOAD_BYTES), qos=1)
        small = out.publish(TOPIC, b"after", qos=1)
        await asyncio.to_thread(huge.wait_for_publish, WAIT_S)  # the broker took it
        await asyncio.to_thread(small.wait_for_publish, WAIT_S)
        await until(lambda: bool(handled), "handled the small command")
        await telemetry.stop()

    out = sender(broker.port)
    try:
        with Subscriber(broker.port, "compd/m/+") as sub:  # birth, event, death; not cmd/...
            asyncio.run(run(sub))
    finally:
        out.loop_stop()
        broker.stop()
    # In order on one topic at QoS 1: had the huge one been sent, it came first.
    assert handled == [b"after"]
    assert not [e for e in sub.of("event") if e["event"] == "fault"], "the daemon never saw it"


@pytest.mark.parametrize(
    ("sent_unix_s", "reason"),
    [
        (NOW - 2 * WINDOW_S, "sent 1200 s ago by this machine's clock"),
        (NOW + WINDOW_S + 5, "sent dated 605 s ahead"),
        (None, "carries no sent_unix_s"),
        ("yesterday", "carries no sent_unix_s"),
        (float("nan"), "a number compd does not read: sent_unix_s: NaN (not a finite number)"),
        (1e400, "sent_unix_s: Infinity (not a finite number)"),
    ],
)
def test_a_stale_undated_or_future_request_is_refused(sent_unix_s: object, reason: str):
    """Only a request sent within WINDOW_S of the machine's clock is taken; the reply says why not."""
    daemon = Daemon(ACCEPTED)
    daemon.handle(request(sent_unix_s=sent_unix_s), now=lambda: NOW)
    assert not daemon.loads
    ((_, reply),) = daemon.replies
    assert reply["result"] == "refused" and reason in reply["reason"]


def test_the_seen_ids_are_kept_inside_the_window_at_most_keep(tmp_path: Path):
    """Ids older than the window and beyond ``keep`` are forgotten; what is kept is read back after a restart."""
    path = tmp_path / "model_requests.json"
    seen = SeenRequests(path, window_s=100.0, keep=3)
    for i, sent in enumerate((0.0, 950.0, 960.0, 970.0, 980.0)):
        seen.add(f"r{i}", sent, now_unix_s=1000.0)
    seen.save(seen.content())
    assert SeenRequests(path, window_s=100.0, keep=3).sent == {
        "r2": 960.0,
        "r3": 970.0,
        "r4": 980.0,
    }


def test_a_seen_ids_file_that_is_not_json_is_started_afresh(tmp_path: Path):
    """A damaged file loses the ids (logged), never the daemon: the age check still holds."""
    path = tmp_path / "model_requests.json"
    path.write_bytes(b"\x00{not json")
    assert SeenRequests(path).sent == {}
    path.write_text(json.dumps({"sent_unix_s": {"a": 1.0, "b": "x", "c": float("inf")}}))
    assert SeenRequests(path).sent == {"a": 1.0}
    for huge in ("1" * 400, "1" * 5000):  # beyond any float; beyond what int() converts
        path.write_text(f'{{"sent_unix_s": {{"a": {huge}}}}}')
        assert SeenRequests(path).sent == {}
