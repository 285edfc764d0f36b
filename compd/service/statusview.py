"""The answer to ``compd status``: a JSON-able snapshot of the running service.

The model (active, pending, blending, faulted), the last tick, every input
with its health, the offsets the stage gives and those the PLC holds, the
driver links and the counters. Built from the live objects on request, between
ticks; nothing here is kept or written.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from datetime import UTC, datetime
from typing import Any

from compd.service.compensator import Compensator
from compd.service.links import DriverLink
from compd.service.ticks import TickTiming


def status_snapshot(
    comp: Compensator,
    links: Mapping[str, DriverLink],
    timing: TickTiming,
    *,
    resumed: bool,
    started_unix_s: float,
    telemetry: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """A JSON-able snapshot: model, last tick, inputs and health, offsets, counters, telemetry."""
    last, counters = comp.last, comp.counters
    return {
        # None: a data logger (no outputs, no model), recording its signals.
        "model": None if comp.models is None else _model(comp),
        "gain_schedule": comp.schedule.status() if comp.schedule is not None else None,
        "resumed": resumed,
        "started": _iso(started_unix_s),
        "last_tick": None if last is None else _iso(last.wall_unix_s),
        "status_word": None if last is None else last.status,
        "heartbeat": comp.heartbeat,
        "offsets_um": {a: s.offset_um for a, s in comp.safety.items()},
        # What the PLC holds as far as compd knows (read back, else acknowledged).
        "offsets_held_um": comp.held.known_um(),
        "targets_um": {} if last is None else last.targets_um,
        "inputs": {
            name: {
                "value": _finite(m.reading.value),
                "health": m.reading.health.name.lower(),
                "reason": m.reading.reason,
            }
            for name, m in comp.monitors.items()
        },
        "drivers": {name: ("up" if link.up else "down") for name, link in links.items()},
        # MQTT telemetry: connected, messages published, acknowledged, dropped; None when off.
        "telemetry": None if telemetry is None else dict(telemetry),
        "counters": {
            "ticks": counters.ticks,
            "overruns": timing.overruns,
            "max_lateness_ms": round(timing.max_lateness_s * 1e3, 3),
            "signal_faults": counters.signal_faults,
            "driver_faults": sum(link.faults for link in links.values()),
            "reconnects": sum(link.reconnects for link in links.values()),
            "write_failures": counters.write_failures,
            "model_loads": counters.model_loads,
            "offset_mismatches": counters.offset_mismatches,
            "model_failures": counters.model_failures,
        },
    }


def _model(comp: Compensator) -> dict[str, Any]:
    slot = comp.active
    return {
        "name": slot.compiled.name,
        "sha256": slot.sha256,
        "path": slot.model_file.path,
        "loaded": _iso(slot.loaded_at_unix_s),
        "started": slot.runner is not None,
        "pending": comp.pending.compiled.name if comp.pending else None,
        "blending_from": comp.previous.compiled.name if comp.previous else None,
        "fault": comp.model_fault,
    }


def _iso(unix_s: float) -> str:
    return datetime.fromtimestamp(unix_s, UTC).isoformat(timespec="seconds")


def _finite(value: float) -> float | None:
    return value if math.isfinite(value) else None
