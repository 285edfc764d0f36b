"""``compd model rollout``: one model file to many machines through the fleet's MQTT broker.

The model is checked here first (as ``compd model check`` does). The broker's
retained births and deaths are read in full (:mod:`compd.cli.fleetstate`);
each machine's retained ``desired`` record then names the model
(:func:`desired_record`), and each machine not known to be offline is sent it
on ``<prefix>/<machine_id>/cmd/model_load`` (:mod:`compd.service.fleet.remoteload`:
the daemon's own checks, install, blend and refusal follow). The answers come
back on ``reply/<request_id>``; with ``--wait-blend`` the ``model_blended``
event says each machine's blend is over. A machine whose retained death says
it is offline is not waited for: it is ``pending`` at once, and takes the
desired record itself when it is back (a daemon with ``accept_models``), or is
sent it if it comes back during the roll-out. One that does not answer in
time is shown with what its retained birth and death say: online, offline
since its death, or never seen on this broker. The command itself:
:mod:`compd.cli.rolloutcommand`.
"""

from __future__ import annotations

import getpass
import hashlib
import json
import socket
import time
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from compd.cli.fleetstate import Listener, connected, presence
from compd.errors import ConfigFileError
from compd.files.yamlplace import parse_yaml, read_limited
from compd.service.config.fleetdoc import TelemetryDoc
from compd.service.config.loading import validation_error
from compd.service.control.modelload import load_request
from compd.service.fleet.remoteload import COMMAND, DESIRED, DESIRED_SCHEMA, SCHEMA

#: What each outcome means for the exit status: these are a success.
SUCCEEDED = ("accepted", "already_running", "already_loading", "up_to_date")


@dataclass
class Outcome:
    """One machine's part of a roll-out."""

    machine_id: str
    #: ``accepted``, ``already_running``, ``already_loading``, ``refused``, ``no answer``,
    #: ``pending`` (offline: see the reason), ``up_to_date`` (``--pending``) or ``not_sent``.
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
    """Send ``raw`` to every machine; their outcomes once all answered (and switched) or ``timeout_s``.

    Machines the broker reports offline are ``pending`` at once (not waited
    for), unless they come back before the others have answered: then they
    are sent it too.
    """
    sha256 = hashlib.sha256(raw).hexdigest()
    listener = Listener(section.topic_prefix, machines)
    with connected(section, base_dir, listener, timeout_s) as client:
        request = load_request(raw, name) | {"schema": SCHEMA, "sha256": sha256}
        del request["cmd"]  # the control socket's word; the topic says it here
        request["requested_by"] = f"{getpass.getuser()}@{socket.gethostname()}"
        request["sent_unix_s"] = time.time()  # the machines take it within seenrequests.WINDOW_S
        ids = {m: uuid.uuid4().hex for m in machines}
        desired = desired_record(request)
        for machine in machines:  # first: a machine away now takes it when back
            topic = f"{section.topic_prefix}/{machine}/{DESIRED}"
            client.publish(topic, desired, qos=1, retain=True).wait_for_publish(timeout_s)
        away = {m for m in machines if presence(listener, m).startswith("offline")}
        sent: set[str] = set()
        deadline = time.monotonic() + timeout_s
        while True:
            # A machine back meanwhile may have subscribed before its desired record came: send it.
            for machine in [m for m in machines if m not in sent and m not in away]:
                request["sent_unix_s"] = time.time()
                payload = json.dumps(request | {"request_id": ids[machine]}).encode()
                topic = f"{section.topic_prefix}/{machine}/cmd/{COMMAND}"
                client.publish(topic, payload, qos=1).wait_for_publish(timeout_s)
                sent.add(machine)
            outcomes = [
                _outcome(listener, m, ids[m], sha256, wait_blend)
                if m in sent
                else _away(listener, m)
                for m in machines
            ]
            if all(_settled(o) for o in outcomes) or time.monotonic() > deadline:
                return outcomes
            time.sleep(0.05)
            away = {m for m in away if presence(listener, m) != "online"}


def when_back(listener: Listener, machine: str) -> str:
    """How a machine away gets its desired model, from what its last birth says it takes."""
    births = listener.of(machine, "birth")
    commands = births[-1].get("commands") if births else None
    if isinstance(commands, list) and COMMAND in commands:
        return "away: takes the desired model itself when it is back (accept_models)"
    if isinstance(commands, list):
        return (
            "away, and takes no models from the network (accept_models: false): "
            "load it there (compd model load)"
        )
    return "away: sent when it is back (run --pending again; an older compd)"


def _away(listener: Listener, machine: str) -> Outcome:
    where = presence(listener, machine)
    return Outcome(machine, "pending", reason=when_back(listener, machine), presence=where)


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

    A daemon with ``accept_models`` takes it when it hears it at connecting
    (a machine that was away, :meth:`compd.service.fleet.remoteload.RemoteLoads.take_desired`:
    the same checks as a command), and names it in its birth; ``--pending``
    sends it to older daemons. It is kept on ``desired``, not ``cmd``: a
    retained command is refused (:mod:`compd.service.fleet.remoteload`), and a
    record is overwritten by the next roll-out, never rolled back to.
    """
    keys = ("name", "model_base64", "sha256", "requested_by", "sent_unix_s")
    record = {"schema": DESIRED_SCHEMA, "rollout_id": uuid.uuid4().hex}
    return json.dumps(record | {k: request[k] for k in keys}).encode()


def _settled(outcome: Outcome) -> bool:
    return outcome.result != "no answer" and outcome.blended_in is not False
