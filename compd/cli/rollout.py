"""``compd model rollout``: one model file to many machines through the fleet's MQTT broker.

The model is checked here first (as ``compd model check`` does), then sent to
each machine's ``<prefix>/<machine_id>/cmd/model_load``
(:mod:`compd.service.fleet.remoteload`: the daemon's own checks, install, blend and
refusal follow). Before that, each machine's retained ``desired`` record
names the model (:func:`desired_record`; ``--pending`` sends it later to a
machine away now). The answers come back on ``reply/<request_id>``; with
``--wait-blend`` the ``model_blended`` event says each machine's blend is
over. A machine that does not answer in time is shown with what its
retained birth and death say: online, offline since its death, or never
seen on this broker. The command itself: :mod:`compd.cli.rolloutcommand`.
"""

from __future__ import annotations

import contextlib
import getpass
import hashlib
import json
import socket
import threading
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import paho.mqtt.client as mqtt
from pydantic import ValidationError

from compd.errors import CompdError, ConfigFileError
from compd.files.yamlplace import parse_yaml, read_limited
from compd.service.config.fleetdoc import TelemetryDoc
from compd.service.config.loading import validation_error
from compd.service.control.modelload import load_request
from compd.service.fleet.mqttlink import broker as broker_of
from compd.service.fleet.mqttlink import mqtt_client
from compd.service.fleet.remoteload import COMMAND, SCHEMA

#: ``<prefix>/<machine_id>/desired`` (retained): the model a roll-out left for the machine.
DESIRED = "desired"
DESIRED_SCHEMA = "compd.desired_model/1"

#: What each outcome means for the exit status: these are a success.
SUCCEEDED = ("accepted", "already_running", "already_loading", "up_to_date")


@dataclass
class Outcome:
    """One machine's part of a roll-out."""

    machine_id: str
    #: ``accepted``, ``already_running``, ``already_loading``, ``refused`` or ``no answer``.
    result: str = "no answer"
    reason: str = ""
    blend_s: float | None = None
    #: ``model_blended`` heard (or a switch without a blend); None: not waited for.
    blended_in: bool | None = None
    #: From the retained birth and death: ``online``, ``offline (...)``, ``never seen``.
    presence: str = "never seen"

    @property
    def ok(self) -> bool:
        return self.result in SUCCEEDED and self.blended_in is not False


def broker_section(path: Path) -> tuple[TelemetryDoc, Path]:
    """The broker settings of ``path``: a compd config's ``telemetry:`` section, or such a section alone.

    ``machine_id`` may be left out (the roll-out is not a machine); files
    (``password_file``, TLS) are relative to ``path``'s folder.
    """
    raw = read_limited(path, ConfigFileError)
    doc, root = parse_yaml(raw.decode("utf-8", errors="replace"), path, ConfigFileError)
    prefix: tuple[str | int, ...] = ()
    if isinstance(doc, dict) and "telemetry" in doc:
        doc, prefix = doc["telemetry"], ("telemetry",)
    if not isinstance(doc, dict):
        raise ConfigFileError(
            path, "no broker settings", fix="Give a 'telemetry:' section: host, port, tls..."
        )
    try:
        section = TelemetryDoc.model_validate({"machine_id": "rollout"} | doc)
    except ValidationError as exc:
        raise validation_error(exc, path, root, prefix) from None
    return section, path.parent


class Listener:
    """What the broker says about the machines: retained birth and death, replies, events."""

    def __init__(self, prefix: str, machines: list[str]) -> None:
        self.prefix = prefix
        self.machines = machines
        self.lock = threading.Lock()
        self.heard: dict[tuple[str, str], list[dict[str, Any]]] = {}
        self.subscribed = threading.Event()
        self.refused = ""

    def topics(self) -> list[tuple[str, int]]:
        kinds = ("birth", "death", "event", "reply/#", "desired")
        return [(f"{self.prefix}/{m}/{kind}", 1) for m in self.machines for kind in kinds]

    def on_connect(self, client: Any, userdata: Any, flags: Any, reason: Any, props: Any) -> None:
        if reason.is_failure:  # a wrong password, an unknown user: say so at once
            self.refused = str(reason)
            self.subscribed.set()
        else:
            client.subscribe(self.topics())

    def on_subscribe(self, *args: Any) -> None:
        self.subscribed.set()

    def on_message(self, client: Any, userdata: Any, message: Any) -> None:
        parts = message.topic.removeprefix(f"{self.prefix}/").split("/")
        try:
            payload = json.loads(message.payload)
        except (ValueError, RecursionError):  # not a reply compd sent: nesting too deep to parse
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


def rollout(
    section: TelemetryDoc,
    base_dir: Path,
    raw: bytes,
    name: str,
    machines: list[str],
    *,
    timeout_s: float,
    wait_blend: bool,
) -> list[Outcome]:
    """Send ``raw`` to every machine; their outcomes once all answered (and switched) or ``timeout_s``."""
    sha256 = hashlib.sha256(raw).hexdigest()
    listener = Listener(section.topic_prefix, machines)
    with connected(section, base_dir, listener, timeout_s) as client:
        request = load_request(raw, name) | {"schema": SCHEMA, "sha256": sha256}
        del request["cmd"]  # the control socket's word; the topic says it here
        request["requested_by"] = f"{getpass.getuser()}@{socket.gethostname()}"
        request["sent_unix_s"] = time.time()  # the machines take it within seenrequests.WINDOW_S
        ids = {m: uuid.uuid4().hex for m in machines}
        desired = desired_record(request)
        for machine in machines:  # first: a machine away now is sent it by --pending later
            topic = f"{section.topic_prefix}/{machine}/{DESIRED}"
            client.publish(topic, desired, qos=1, retain=True).wait_for_publish(timeout_s)
        for machine in machines:
            payload = json.dumps(request | {"request_id": ids[machine]}).encode()
            topic = f"{section.topic_prefix}/{machine}/cmd/{COMMAND}"
            client.publish(topic, payload, qos=1).wait_for_publish(timeout_s)
        deadline = time.monotonic() + timeout_s
        while True:
            outcomes = [_outcome(listener, m, ids[m], sha256, wait_blend) for m in machines]
            if all(_settled(o) for o in outcomes) or time.monotonic() > deadline:
                return outcomes
            time.sleep(0.05)


@contextlib.contextmanager
def connected(
    section: TelemetryDoc, base_dir: Path, listener: Listener, timeout_s: float
) -> Iterator[mqtt.Client]:
    """A client of the broker, logged in, ``listener`` subscribed; disconnected afterwards."""
    broker = broker_of(section, base_dir, f"compd-rollout-{uuid.uuid4().hex[:12]}")
    client = mqtt_client(broker)
    client.on_connect = listener.on_connect
    client.on_subscribe = listener.on_subscribe
    client.on_message = listener.on_message
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
        yield client
    finally:
        client.disconnect()
        client.loop_stop()


def _outcome(listener: Listener, machine: str, request_id: str, sha256: str, wait: bool) -> Outcome:
    outcome = Outcome(machine, presence=presence(listener, machine))
    for reply in listener.of(machine, "reply"):
        if reply.get("request_id") == request_id:
            outcome.result = str(reply.get("result", "refused"))
            outcome.reason = str(reply.get("reason", ""))
            outcome.blend_s = reply.get("blend_s")
    if wait and outcome.result in SUCCEEDED:
        outcome.blended_in = outcome.result == "already_running" or any(
            e.get("details", {}).get("sha256") == sha256
            and (
                e.get("event") == "model_blended"
                or (e.get("event") == "model_switched" and not e["details"].get("blending"))
            )
            for e in listener.of(machine, "event")
        )
    return outcome


def desired_record(request: dict[str, Any]) -> bytes:
    """The retained record of what a roll-out asked: the model itself, never a command.

    Machines read it only to say in their birth whether they run it; the
    model travels in it so that ``--pending`` can send it later. Kept on
    ``desired``, which no daemon acts on (a retained ``cmd`` would be loaded
    again at every connection, and is refused: :mod:`compd.service.fleet.remoteload`).
    """
    keys = ("name", "model_base64", "sha256", "requested_by", "sent_unix_s")
    record = {"schema": DESIRED_SCHEMA, "rollout_id": uuid.uuid4().hex}
    return json.dumps(record | {k: request[k] for k in keys}).encode()


def _settled(outcome: Outcome) -> bool:
    return outcome.result != "no answer" and outcome.blended_in is not False


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
