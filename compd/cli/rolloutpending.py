"""``compd model rollout --pending``: finish the roll-outs that machines away at the time missed.

Every roll-out leaves, per machine, a retained record on
``<prefix>/<machine_id>/desired`` (:func:`compd.cli.rollout.desired_record`:
the model and its sha256). This reads those records with the machines'
retained births and deaths, all of them (:mod:`compd.cli.fleetstate`), and
sends each online machine whose birth names another model the one its
record asks for (the same request and checks as a roll-out). Machines still
away stay pending: a daemon with ``accept_models`` takes its record itself
when it is back; for an older one run this again (from cron, or after a
machine comes back).
"""

from __future__ import annotations

import base64
import hashlib
from pathlib import Path

from compd.cli.fleetstate import Listener, connected, presence
from compd.cli.rollout import Outcome, rollout, when_back
from compd.service.config.fleetdoc import TelemetryDoc
from compd.service.fleet.remoteload import DESIRED, DESIRED_SCHEMA


def retained(section: TelemetryDoc, base_dir: Path, timeout_s: float) -> Listener:
    """What the broker retains for every machine: births, deaths, desired records, all of them."""
    listener = Listener(section.topic_prefix, ["+"], ("birth", "death", DESIRED))
    with connected(section, base_dir, listener, timeout_s):
        pass  # connected() returns once the marker is back: every retained message heard
    return listener


def online(section: TelemetryDoc, base_dir: Path, timeout_s: float) -> list[str]:
    """Every machine whose retained birth and death say it is online now (``--online``)."""
    listener = retained(section, base_dir, timeout_s)
    machines = listener.machines_heard("birth")
    return sorted(m for m in machines if presence(listener, m) == "online")


def pending(
    section: TelemetryDoc,
    base_dir: Path,
    machines: list[str] | None,
    *,
    timeout_s: float,
    wait_blend: bool,
) -> list[Outcome]:
    """The outcome per machine with a desired record (of ``machines``, or every one)."""
    listener = retained(section, base_dir, timeout_s)
    records = {m: listener.of(m, DESIRED)[-1] for m in listener.machines_heard(DESIRED)}
    outcomes: list[Outcome] = []
    to_send: dict[str, list[str]] = {}
    for machine in sorted(records):
        record = records[machine]
        if (machines and machine not in machines) or record.get("schema") != DESIRED_SCHEMA:
            continue
        births = listener.of(machine, "birth")
        running = (births[-1].get("model") or {}).get("sha256") if births else None
        where = presence(listener, machine)
        if running == record.get("sha256"):
            outcomes.append(Outcome(machine, "up_to_date", presence=where))
        elif where != "online":
            reason = when_back(listener, machine)
            outcomes.append(Outcome(machine, "pending", reason=reason, presence=where))
        else:
            to_send.setdefault(str(record.get("sha256")), []).append(machine)
    for sha256, group in to_send.items():
        record = records[group[0]]
        raw = base64.b64decode(str(record.get("model_base64", "")), validate=True)
        if hashlib.sha256(raw).hexdigest() != sha256:
            reason = "the desired record's model does not match its sha256: roll it out again"
            outcomes += [Outcome(m, "refused", reason=reason, presence="online") for m in group]
            continue
        name = str(record.get("name", "model.yaml"))
        outcomes += rollout(
            section, base_dir, raw, name, group, timeout_s=timeout_s, wait_blend=wait_blend
        )
    return sorted(outcomes, key=lambda o: o.machine_id)
