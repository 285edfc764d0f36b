"""Models rolled out over the broker, the daemon's side: the request's checks, the size bound, off by default.

The whole path (``compd model rollout`` to three running daemons, refusals,
an ACL over TLS) is in ``tests/acceptance/test_fleet.py``; here each check
that stands between a broker message and ``Service.load_model``.
"""

from __future__ import annotations

import asyncio
import base64
import hashlib
import json
import time
from pathlib import Path
from typing import Any

import paho.mqtt.client as mqtt
import pytest
from paho.mqtt.enums import CallbackAPIVersion

from compd.errors import CompdError
from compd.faultlog import Event
from compd.files.yamlplace import MAX_YAML_BYTES
from compd.service.daemon import Service
from compd.service.fleet.mqttlink import Broker, Topics
from compd.service.fleet.remoteload import DESIRED_SCHEMA, MAX_PAYLOAD_BYTES, SCHEMA, RemoteLoads
from compd.service.fleet.telemetry import Telemetry
from compd.service.fleet.wirecheck import TOO_DEEP
from compd.service.loop.clock import VirtualClock
from tests.mosquitto import MODEL, WAIT_S, Mosquitto, Subscriber, machine_config, mosquitto_binary
from tests.service.daemon_setup import write_config

RAW = MODEL.read_bytes()


def request(**changes: Any) -> bytes:
    body = {
        "schema": SCHEMA,
        "request_id": "r1",
        "name": "twin-z.yaml",
        "model_base64": base64.b64encode(RAW).decode(),
        "sha256": hashlib.sha256(RAW).hexdigest(),
        "requested_by": "test",
        "sent_unix_s": time.time(),
    }
    return json.dumps({k: v for k, v in (body | changes).items() if v is not None}).encode()


class Daemon:
    """What a RemoteLoads talks to, recorded: the loads it asks for, its replies and events."""

    def __init__(self, answer: dict[str, Any] | Exception) -> None:
        self.answer = answer
        self.loads: list[dict[str, Any]] = []
        self.replies: list[tuple[str, dict[str, Any]]] = []
        self.events: list[Event] = []

    async def load(self, message: dict[str, Any]) -> dict[str, Any]:
        self.loads.append(message)
        if isinstance(self.answer, Exception):
            raise self.answer
        return self.answer

    def handle(self, payload: bytes, *, retained: bool = False, **options: Any) -> None:
        """``payload`` through a RemoteLoads of its own (``options``: its ``seen``, ``now``)."""
        remote = RemoteLoads(
            self.load, lambda i, r: self.replies.append((i, r)), self.events.append, **options
        )
        asyncio.run(remote.handle(payload, retained=retained))


ACCEPTED = {"model": "twin-z", "sha256": "x", "installed": "/s/m.yaml", "blend_s": 60.0}


def test_an_accepted_load_is_the_control_sockets_load_and_answered_on_its_request_id():
    """The model's bytes go to Service.load_model as a control-socket load; the answer names the blend."""
    daemon = Daemon(ACCEPTED)
    daemon.handle(request())
    assert [m["cmd"] for m in daemon.loads] == ["load"]
    assert base64.b64decode(daemon.loads[0]["model_base64"]) == RAW
    ((request_id, reply),) = daemon.replies
    assert request_id == "r1"
    assert reply["result"] == "accepted" and reply["blend_s"] == 60.0


def test_the_running_model_sent_again_is_already_running():
    """load_model's already_running is passed on: nothing loaded, no blend."""
    daemon = Daemon({"model": "twin-z", "sha256": "x", "installed": "/s", "already_running": True})
    daemon.handle(request())
    assert daemon.replies[0][1]["result"] == "already_running"


@pytest.mark.parametrize(
    ("changes", "reason"),
    [
        ({"sha256": "0" * 64}, "altered or truncated"),
        ({"schema": "compd.model_load/9"}, "schema"),
        ({"model_base64": "not base64!"}, "not base64"),
        ({"model_base64": None}, "model_base64"),
    ],
)
def test_a_request_that_does_not_hold_together_is_refused_unloaded(
    changes: dict[str, Any], reason: str
):
    """Wrong sha256, schema or encoding: refused with the reason, an event, and load_model never called."""
    daemon = Daemon(ACCEPTED)
    daemon.handle(request(**changes))
    assert not daemon.loads
    reply = daemon.replies[0][1]
    assert reply["result"] == "refused" and reason in reply["reason"]
    assert [e.kind for e in daemon.events] == ["model_refused"]


def test_a_model_the_daemon_refuses_is_answered_refused_with_its_reason():
    """load_model's CompdError (a model that does not fit the config) is the answer's reason."""
    daemon = Daemon(CompdError("model signal 'T_x' is not in the config"))
    daemon.handle(request())
    reply = daemon.replies[0][1]
    assert reply == reply | {
        "result": "refused",
        "reason": "model signal 'T_x' is not in the config",
    }


@pytest.mark.parametrize(
    "payload", [b"\xff not json", b"[1]", request(request_id="a/b"), request(request_id=None)]
)
def test_a_request_without_a_usable_id_gets_no_answer_but_an_event(payload: bytes):
    """Not JSON, not an object, or a request_id that is no topic level: nothing to answer to; told as an event."""
    daemon = Daemon(ACCEPTED)
    daemon.handle(payload)
    assert not daemon.loads and not daemon.replies
    assert [e.kind for e in daemon.events] == ["model_refused"]


def test_a_request_nested_too_deeply_is_refused_as_an_event_not_a_traceback():
    """A payload of 1M "[" (inside the size bound, deeper than Python's JSON parser recurses) is refused as an event."""
    payload = b"[" * 1_000_000
    assert len(payload) <= MAX_PAYLOAD_BYTES
    daemon = Daemon(ACCEPTED)
    daemon.handle(payload)
    assert not daemon.loads and not daemon.replies
    (event,) = daemon.events
    assert event.kind == "model_refused" and TOO_DEEP in event.details["reason"]


@pytest.mark.parametrize(
    ("field", "number", "reason"),
    [
        ("sent_unix_s", "1" * 5000, "sent_unix_s: an integer of 5000 digits"),
        ("sent_unix_s", "1e400", "sent_unix_s: 1e400 (beyond any float)"),
        ("requested_by", "-Infinity", "requested_by: -Infinity (not a finite number)"),
    ],
)
def test_a_number_compd_does_not_read_is_refused_with_an_answer(
    field: str, number: str, reason: str
):
    """An integer of 5,000 digits, 1e400 or -Infinity in the request: refused, answered and told, never a traceback."""
    payload = json.loads(request())
    payload[field] = "NUMBER"
    daemon = Daemon(ACCEPTED)
    daemon.handle(json.dumps(payload).replace('"NUMBER"', number).encode())
    assert not daemon.loads
    ((request_id, reply),) = daemon.replies
    assert request_id == "r1" and reply["result"] == "refused"
    assert reply["reason"] == f"the request holds a number compd does not read: {reason}"
    assert [e.kind for e in daemon.events] == ["model_refused"]


def test_a_model_of_a_5000_digit_gain_is_refused_with_an_answer(tmp_path: Path):
    """The model inside the request holds an integer of 5,000 digits: the daemon's load refuses it, named."""
    config = write_config(tmp_path)
    text = config.model_path.read_text()
    raw = text.replace("gain: 1.0", "gain: " + "9" * 5000, 1).encode()
    sha256 = hashlib.sha256(raw).hexdigest()
    service = Service(config, clock=VirtualClock(), control=False)
    daemon = Daemon(ACCEPTED)
    daemon.load = service.load_model  # type: ignore[method-assign]
    daemon.handle(request(model_base64=base64.b64encode(raw).decode(), sha256=sha256))
    ((_, reply),) = daemon.replies
    assert reply["result"] == "refused", reply
    assert ".gain): " in reply["reason"] and "an integer of 5000 digits" in reply["reason"]
    assert [e.kind for e in daemon.events] == ["model_refused"]


def test_a_failure_checking_a_request_is_answered_refused():
    """An exception that is no refusal (a bug) still answers the sender, and is told as an event."""
    daemon = Daemon(ZeroDivisionError("bug"))
    daemon.handle(request())
    ((_, reply),) = daemon.replies
    assert reply["result"] == "refused" and "ZeroDivisionError" in reply["reason"]
    assert [e.kind for e in daemon.events] == ["model_refused"]


def test_models_from_the_network_are_off_unless_the_config_says_so(tmp_path: Path):
    """Telemetry alone subscribes to no command; accept_models: true to cmd/model_load."""
    telemetry = {"machine_id": "m", "host": "127.0.0.1", "port": 1}
    plain = machine_config(tmp_path / "plain", telemetry=telemetry)
    accepting = machine_config(
        tmp_path / "accepting", telemetry=telemetry | {"accept_models": True}
    )
    listening = []
    for config in (plain, accepting):
        service = Service(config, clock=VirtualClock(), control=False)
        assert service.telemetry is not None
        listening.append(service.telemetry.listening)
    assert listening == [(), ("model_load",)]


@pytest.mark.skipif(
    mosquitto_binary() is None, reason="mosquitto is not installed: run .ci/install-system-packages"
)
def test_a_payload_over_the_bound_is_dropped_unread(tmp_path: Path):
    """Through a real mosquitto: a payload just over max_bytes never reaches the handler; it is told as a fault."""
    broker = Mosquitto(tmp_path).start()
    handled: list[bytes] = []

    async def handler(payload: bytes, *, retained: bool = False) -> None:
        handled.append(payload)

    async def run() -> None:
        telemetry = Telemetry(Broker("127.0.0.1", broker.port, "compd-m"), Topics("compd", "m"))
        telemetry.listen("model_load", handler, max_bytes=100)
        telemetry.start()
        deadline = time.monotonic() + WAIT_S
        while not sub.of("birth"):  # born: subscribed to its commands before
            assert time.monotonic() < deadline
            await asyncio.sleep(0.01)
        for size in (101, 100):
            sender.publish("compd/m/cmd/model_load", b"x" * size, qos=1).wait_for_publish(WAIT_S)
        while not handled or not sub.of("event"):
            assert time.monotonic() < deadline, "never handled"
            await asyncio.sleep(0.01)
        await telemetry.stop()

    sender = mqtt.Client(CallbackAPIVersion.VERSION2, client_id="sender")
    try:
        with Subscriber(broker.port, "compd/+/+") as sub:  # birth, event; not cmd/...
            sender.connect("127.0.0.1", broker.port)
            sender.loop_start()
            asyncio.run(run())
            sender.loop_stop()
    finally:
        broker.stop()
    assert handled == [b"x" * 100]
    (fault,) = sub.of("event")
    assert fault["event"] == "fault" and fault["details"]["bytes"] == 101


def test_a_model_file_at_its_size_limit_fits_the_payload_bound():
    """The bound is the model file's own (MAX_YAML_BYTES), base64-encoded, with the request's fields."""
    raw = b"#" * MAX_YAML_BYTES
    body = json.loads(request())
    body |= {"model_base64": base64.b64encode(raw).decode(), "requested_by": "x" * 200}
    assert len(json.dumps(body).encode()) <= MAX_PAYLOAD_BYTES


def desired(**changes: Any) -> bytes:
    """A roll-out's retained desired record of RAW (``compd.cli.rollout.desired_record``'s shape)."""
    record = json.loads(request(**changes))
    record |= {"schema": changes.get("schema", DESIRED_SCHEMA), "rollout_id": "o1"}
    return json.dumps({k: v for k, v in record.items() if k != "request_id"}).encode()


def take(daemon: Daemon, *payloads: bytes, installed: bool = False) -> None:
    """``payloads`` through one RemoteLoads's take_desired, in turn (one process: one memory).

    ``installed``: the state directory holds the model (it ran here before).
    """
    remote = RemoteLoads(
        daemon.load,
        lambda i, r: daemon.replies.append((i, r)),
        daemon.events.append,
        installed=lambda sha256: installed,
    )

    async def each() -> None:
        for payload in payloads:
            await remote.take_desired(payload)

    asyncio.run(each())


def test_a_desired_record_is_loaded_as_a_command_is_however_old():
    """A machine back days later: its desired record goes to load_model; no reply (no request)."""
    daemon = Daemon(ACCEPTED)
    take(daemon, desired(sent_unix_s=time.time() - 30 * 86400))
    assert [base64.b64decode(m["model_base64"]) for m in daemon.loads] == [RAW]
    assert not daemon.replies and not daemon.events


@pytest.mark.parametrize(
    ("changes", "reason"),
    [
        ({"sha256": "0" * 64}, "altered or truncated"),
        ({"schema": "compd.model_load/1"}, "schema"),
        ({"model_base64": "not base64!"}, "not base64"),
        ({"sent_unix_s": 1e400}, "does not read"),
    ],
)
def test_a_desired_record_that_does_not_hold_together_is_refused_once(
    changes: dict[str, Any], reason: str
):
    """Refused unloaded, with a model_refused event naming the roll-out; heard again, not retried."""
    daemon = Daemon(ACCEPTED)
    payload = desired(**changes).replace(b"Infinity", b"1e400")
    take(daemon, payload, payload)
    assert not daemon.loads
    (event,) = daemon.events
    assert event.kind == "model_refused" and event.message == "desired model refused"
    assert reason in event.details["reason"] and event.details["rollout_id"] == "o1"


def test_a_desired_model_the_daemon_refuses_is_told_and_the_running_one_stays():
    """load_model's CompdError (unstable, another config's signals) is the event's reason."""
    daemon = Daemon(CompdError("the model is not stable"))
    take(daemon, desired(), desired())
    assert len(daemon.loads) == 1, "refused once, not at every reconnection"
    assert [e.details["reason"] for e in daemon.events] == ["the model is not stable"]


def test_a_desired_model_that_ran_here_and_was_replaced_here_is_not_taken_again():
    """Unloaded by a failure, or a person loaded another since: the machine's own choice stands."""
    daemon = Daemon(ACCEPTED)
    take(daemon, desired(), installed=True)
    assert not daemon.loads
    (event,) = daemon.events
    assert "replaced here" in event.details["reason"] and "--pending" in event.details["reason"]
