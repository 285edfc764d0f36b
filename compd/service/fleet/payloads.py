"""The JSON objects a daemon's telemetry publishes: header, birth, status, event, death and will.

Every payload starts with the same header (``schema``, ``kind``,
``machine_id``, ``session``, ``seq``, ``time``); see docs/fleet.md, "Telemetry",
for each kind's fields. The numbers are in engineering units, said once in
the birth (``units``, each signal's ``unit`` and its Prometheus ``metric``),
and health both as a word and as ``compd_signal_health``'s code.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import structlog

from compd.faultlog import Event, EventSink
from compd.service.fleet.claim import Instance
from compd.service.fleet.jsonwire import SCHEMA, compd_version, finite, finites
from compd.service.fleet.mqttlink import Topics

if TYPE_CHECKING:
    from compd.service.loop.compensator import TickRecord

log = structlog.get_logger("compd.service.fleet.telemetry")

#: The fields of a roll-out's desired record a birth repeats.
DESIRED_KEYS = ("sha256", "name", "rollout_id", "requested_by", "sent_unix_s")


class Payloads:
    """Builds one daemon's payloads; ``session`` and ``seq`` number its connections and messages."""

    def __init__(
        self,
        topics: Topics,
        instance: Instance,
        *,
        every_ticks: int,
        identity: Callable[[], dict[str, Any]],
        wall: Callable[[], float],
    ) -> None:
        self.topics = topics
        self.instance = instance
        self.every_ticks = every_ticks
        self.identity = identity
        self.wall = wall
        # Sparkplug's bdSeq: numbers the connections, across restarts too (milliseconds at start).
        self.session = int(time.time() * 1000)
        self.seq = 0
        #: The fleet's desired model for this machine (``desired``, retained by the roll-out), if any.
        self.desired: dict[str, Any] | None = None
        self._told_outdated = ""

    def header(self, kind: str) -> dict[str, Any]:
        """The fields every payload starts with; ``machine_time`` where the service's clock is not
        the real one (``--time-scale``, a simulation on virtual time)."""
        self.seq += 1
        now_unix_s, machine_s = time.time(), self.wall()
        return {
            "schema": SCHEMA,
            "kind": kind,
            "machine_id": self.topics.machine_id,
            "session": self.session,
            "seq": self.seq,
            # When it was sent, on the real clock: what a fleet reads of a birth or a death;
            # a status or an event carries its tick's time instead (the service's clock).
            "time": now_unix_s,
        } | ({} if abs(machine_s - now_unix_s) < 1.0 else {"machine_time": machine_s})

    def birth(self, events: EventSink) -> dict[str, Any]:
        """Who publishes; ``events`` hears ``model_outdated`` once per desired model not run."""
        birth = self.header("birth")
        birth |= {"compd_version": compd_version(), "every_ticks": self.every_ticks}
        birth |= {"instance": self.instance.describe()} | self.identity()
        desired = self.desired
        if desired is not None:
            running = (birth.get("model") or {}).get("sha256")
            birth["desired_model"] = desired | {"runs_it": running == desired["sha256"]}
            if running != desired["sha256"] and self._told_outdated != desired["sha256"]:
                self._told_outdated = str(desired["sha256"])
                details = {"running": running, "desired": desired["sha256"]}
                message = "runs another model than the fleet's desired one"
                log.warning(message, **details)  # the journal hears it too, not only MQTT
                events(Event("model_outdated", message, details))
        return birth

    def event(self, at_s: float, event: Event) -> dict[str, Any]:
        payload = self.header("event") | {"time": at_s}
        return payload | {"event": event.kind, "message": event.message, "details": event.details}

    def death(self, reason: str, **fields: Any) -> dict[str, Any]:
        """A clean stop's death; :meth:`will` is the broker's."""
        death = self.header("death") | {"reason": reason} | fields
        return death | {"instance": self.instance.describe()}

    def will(self) -> dict[str, Any]:
        """The death the broker publishes if the connection goes: stamped when it is made."""
        return self.death("connection lost", time_is="connected")

    def status(
        self,
        record: TickRecord,
        counters: dict[str, int],
        model: str | None,
        dropped: int,
        *,
        probes: dict[str, Any] | None = None,
    ) -> dict[str, Any]:
        """One tick's status; with ``probes`` (a config that probes), per axis what they say now:
        due, the last probe and its innovation, the shift's RMS of the residues, the adjustment."""
        payload = self.header("status") | {"time": record.wall_unix_s}
        if probes is not None:
            payload["probes"] = probes
        return payload | {
            "t_s": record.t_s,
            "model": model,
            "inputs": {
                name: {
                    "value": finite(value),
                    "health": record.health[name].name.lower(),
                    "health_code": int(record.health[name]),  # as compd_signal_health
                    "reason": record.reasons.get(name, ""),
                }
                for name, value in record.values.items()
            },
            "model_outputs": finites(record.model_outputs),
            "targets_um": finites(record.targets_um),
            "offsets_um": finites(record.offsets_um),
            "acknowledged_um": finites(record.acknowledged_um),
            "written": record.written,
            "status_word": record.status,
            "heartbeat": record.heartbeat,
            "counters": counters | {"telemetry_dropped": dropped},
        }
