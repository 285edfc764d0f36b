"""The soak's fleet roll-out: one ``cmd/model_load`` taken once; its retained copy and its replay refused.

A roll-out command left retained on the broker is handed to the daemon again
at every connection, and a captured one can be sent again: both must be
refused (:mod:`compd.service.fleet.remoteload`), by every service of the soak,
across its kills and restarts (the ids taken are kept in the state
directory). The soak has no broker: each service gets the deliveries a
broker would make, through the same :class:`~compd.service.fleet.remoteload.RemoteLoads`
the daemon builds for its MQTT link. The command carries the running model
(taken as ``already_running``: the shift's compensation is not changed).
"""

from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path
from typing import Any

from compd.service.control.modelload import load_request
from compd.service.daemon import Service
from compd.service.fleet.remoteload import SCHEMA, RemoteLoads
from compd.service.fleet.seenrequests import FILE, SeenRequests
from compd.sim.soakwitness import SoakResult

REQUEST_ID = "soak-rollout-1"


def rollout_command(model: bytes) -> bytes:
    """What ``compd model rollout`` publishes for ``model``, stamped now (real time, as it does)."""
    request = load_request(model, "rolled-out.yaml") | {"schema": SCHEMA, "request_id": REQUEST_ID}
    del request["cmd"]
    request |= {"sha256": hashlib.sha256(model).hexdigest(), "sent_unix_s": time.time()}
    return json.dumps(request | {"requested_by": "soak"}).encode()


async def deliver(
    service: Service, state_dir: Path, command: bytes, result: SoakResult, *, first: bool
) -> None:
    """The first service takes ``command`` as sent; every service then gets it retained, and replayed."""
    answers: list[dict[str, Any]] = []
    seen = SeenRequests(state_dir / FILE)
    remote = RemoteLoads(
        service.load_model, lambda _, answer: answers.append(answer), lambda _: None, seen=seen
    )
    if first:
        await remote.handle(command)
        result.rollouts_taken += answers.pop()["result"] != "refused"
    await remote.handle(command, retained=True)
    await remote.handle(command)
    for answer in answers:
        if answer["result"] == "refused":
            result.rollouts_refused += 1
        else:
            result.rollouts_taken_again += 1
            result.errors.append(f"a retained or replayed roll-out was taken: {answer}")
