"""The answer to ``compd status``: a JSON-able snapshot of the running service.

The model (active, pending, blending, faulted), the last tick and how long
ago it ran, every input with its value, unit and health, the offsets the
stage gives and those the PLC holds, the driver links and the counters. Built
from the live objects on request, between ticks; nothing here is kept or written.

Times are the wall clock's (UTC, ISO 8601), also under ``--time-scale``: the
loop's clock then runs X times faster, and its stamps (the records', the saved
state's) would lie in the future. Each is taken back to the real time it
happened (``real now - clock age / X``); the clock's own time is given apart,
as ``clock.machine_time``. On virtual time (``--time-scale max``) there is no
real time to take it back to: the stamps are the machine's, and
``clock.time_scale`` is ``"max"`` to say so.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from datetime import UTC, datetime
from typing import Any

from compd.model.verifiable import Unverifiable
from compd.service.loop.clock import Clock
from compd.service.loop.compensator import Compensator
from compd.service.loop.links import DriverLink
from compd.service.loop.safety import Level
from compd.service.loop.signals import Health
from compd.service.loop.ticks import TickTiming

#: ``/healthz``: a last tick older than this many periods means the loop is stuck.
LATE_PERIODS = 3.0


def status_snapshot(
    comp: Compensator,
    links: Mapping[str, DriverLink],
    timing: TickTiming,
    *,
    clock: Clock,
    units: Mapping[str, str],
    resumed: bool,
    started_unix_s: float,
    counters: Mapping[str, int],
    telemetry: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """A JSON-able snapshot: model, last tick and its age, inputs with units and health, offsets,
    counters, telemetry."""
    last = comp.last
    clock_now_s = clock.wall()
    scale = getattr(clock, "time_scale", None)  # None: virtual time

    def age_s(stamp_unix_s: float) -> float:
        """Seconds since a clock stamp: real seconds, or the machine's on virtual time."""
        return (clock_now_s - stamp_unix_s) / (scale or 1.0)

    def when(stamp_unix_s: float) -> str:
        real_unix_s = stamp_unix_s if scale is None else time.time() - age_s(stamp_unix_s)
        return _iso(real_unix_s)

    return {
        "clock": {
            "time_scale": "max" if scale is None else scale,
            "machine_time": _iso(clock_now_s),
        },
        # None: a data logger (no outputs, no model), recording its signals.
        "model": None if comp.models is None else _model(comp, when),
        "gain_schedule": comp.schedule.status() if comp.schedule is not None else None,
        # Each model input with a second sensor (:mod:`compd.service.loop.redundancy`).
        "redundant": {}
        if comp.redundancy is None
        else {c.pair.primary: c.status() for c in comp.redundancy.checks},
        "resumed": resumed,
        "started": when(started_unix_s),
        "last_tick": None if last is None else when(last.wall_unix_s),
        "last_tick_age_s": None if last is None else round(age_s(last.wall_unix_s), 3),
        "status_word": None if last is None else last.status,
        # The word's level (bits 0-1) in words: ok, degraded or faulted.
        "level": None if last is None else Level(last.status & 0b11).name.lower(),
        "heartbeat": comp.heartbeat,
        "offsets_um": {a: s.offset_um for a, s in comp.safety.items()},
        # What the PLC holds as far as compd knows (read back, else acknowledged).
        "offsets_held_um": comp.held.known_um(),
        # Per axis whose offset the last tick did not write (the device did not acknowledge
        # it), why: its driver's link, e.g. "plc link down"; absent while it is written.
        "offsets_not_written": _not_written(comp, links),
        # The offset each axis aims at: sign x the model's output (its predicted drift).
        "targets_um": {} if last is None else last.targets_um,
        "signs": {axis.name: axis.sign for axis in comp.axes},
        # Per axis: its envelope, how long its target has been outside it and why
        # (:mod:`compd.service.loop.envelope`); ``faulted`` once that lasted envelope_after_s.
        "envelope": {
            name: {
                "envelope": stage.watch.envelope.describe(),
                "band_um": stage.watch.envelope.band_um,
                "outside": stage.watch.sentence(name),
                "outside_s": round(stage.watch.outside_s, 1),
                "faulted": stage.watch.faulted,
            }
            for name, stage in comp.safety.items()
        },
        "inputs": {
            name: {
                "value": _finite(m.reading.value),
                "unit": units.get(name, ""),
                "health": m.reading.health.name.lower(),
                "reason": m.reading.reason,
            }
            for name, m in comp.monitors.items()
        },
        # "not connected": it has not answered once since start (a PLC off, a wrong address).
        "drivers": {name: link.state for name, link in links.items()},
        # MQTT telemetry: connected, messages published, acknowledged, dropped; None when off.
        "telemetry": None if telemetry is None else dict(telemetry),
        # The last tick's counters, as telemetry and the metrics give them.
        "counters": {
            "ticks": counters["ticks"],
            "overruns": counters["overruns"],
            "max_lateness_ms": round(timing.max_lateness_s * 1e3, 3),
            **{k: v for k, v in counters.items() if k not in ("ticks", "overruns")},
        },
    }


def health_problems(
    comp: Compensator,
    links: Mapping[str, DriverLink],
    timing: TickTiming,
    *,
    clock: Clock,
    period_s: float,
) -> list[str]:
    """Why a load balancer or probe should not trust this daemon now; empty while healthy (``/healthz``).

    Healthy: the last tick ran within :data:`LATE_PERIODS` periods and started on time, every
    driver answers, the outputs were written, the status level is not faulted and the model
    runs. Degraded (an input held or estimated) still compensates, so it is healthy.
    """
    last = comp.last
    if last is None:
        return ["no tick yet: starting"]
    problems = []
    age_s = clock.wall() - last.wall_unix_s  # the loop's clock, as period_s is
    if age_s > LATE_PERIODS * period_s:
        problems.append(f"no tick for {age_s:.1f} s (period {period_s:g} s): the loop is stuck")
    elif timing.last_lateness_s > period_s:
        problems.append(
            f"the last tick started {timing.last_lateness_s:.2f} s late (period {period_s:g} s)"
        )
    problems += [
        f"driver {name} {link.state}" + (f" ({link.last_error})" if link.last_error else "")
        for name, link in links.items()
        if link.state != "up"
    ]
    if comp.axes and not last.written:
        problems.append("the last tick's offsets were not written")
    if Level(last.status & 0b11) is Level.FAULTED:
        faulted = [n for n, h in last.health.items() if h is Health.FAULTED]
        problems.append("status faulted" + (f": {', '.join(faulted)}" if faulted else ""))
    if comp.model_fault:
        problems.append(f"model fault: {comp.model_fault}")
    problems += [
        f"envelope: {said}"
        for name, stage in comp.safety.items()
        if stage.watch.faulted and (said := stage.watch.sentence(name)) is not None
    ]
    return problems


def _not_written(comp: Compensator, links: Mapping[str, DriverLink]) -> dict[str, str]:
    """Per axis the last tick wrote no offset to, why, in a few words (``plc link down``)."""
    last = comp.last
    if last is None:
        return {}
    why = {}
    for axis in comp.axes:
        if math.isnan(last.acknowledged_um.get(axis.name, math.nan)):
            link = links.get(axis.driver)
            state = "unknown" if link is None else link.state
            why[axis.name] = (
                f"{axis.driver} not acknowledged"
                if state == "up"
                else f"{axis.driver} link {state}"
            )
    return why


def _model(comp: Compensator, when: Callable[[float], str]) -> dict[str, Any]:
    slot = comp.active
    return {
        "name": slot.compiled.name,
        "sha256": slot.sha256,
        "path": slot.model_file.path,
        "loaded": when(slot.loaded_at_unix_s),
        "started": slot.runner is not None,
        "initialised": slot.initialised,
        "pending": comp.pending.compiled.name if comp.pending else None,
        "blending_from": comp.previous.compiled.name if comp.previous else None,
        "fault": comp.model_fault,
    }


def _iso(unix_s: float) -> str:
    return datetime.fromtimestamp(unix_s, UTC).isoformat(timespec="seconds")


def _finite(value: float) -> float | None:
    return value if math.isfinite(value) else None


def unverifiable_status(
    rows: Sequence[Unverifiable], units: Mapping[str, str]
) -> list[dict[str, Any]]:
    """``compd status``'s ``unverifiable``: per input and axis, what a wrong reading can move the axis
    by unseen (:mod:`compd.model.verifiable`); ``undetectable_um`` None where nothing checks the input."""
    return [
        {
            "input": r.input,
            "axis": r.axis,
            "unit": units.get(r.input, ""),
            "detected_by": r.detection.by,
            "threshold": _finite(r.detection.threshold),
            "um_per_unit": r.um_per_unit,
            "undetectable_um": _finite(r.undetectable_um),
            "tolerance_um": r.tolerance_um,
            "verifiable": not r.exceeds,
            "remedy": r.remedy,
        }
        for r in rows
    ]


def not_assured(
    unverifiable: Sequence[Mapping[str, Any]], *, disagreeing: Sequence[str], also: Sequence[str]
) -> list[str]:
    """``also`` (e.g. the state not saved), then one line per axis whose compensation is not
    assured though the status word's level may read ok: the inputs (:func:`unverifiable_status`'s
    rows) whose wrong reading the sensors cannot see within its tolerance, and the axes whose
    probes disagree with the model (two in a row not taken)."""
    unseen: dict[str, list[Mapping[str, Any]]] = {}
    for row in unverifiable:
        if not row["verifiable"]:
            unseen.setdefault(row["axis"], []).append(row)
    return [
        *also,
        *(
            f"not assured on {axis}: {', '.join(r['input'] for r in rows)} "
            f"not verifiable to its {rows[0]['tolerance_um']:.3g} um tolerance"
            for axis, rows in unseen.items()
        ),
        *(
            f"not assured on {axis}: two probes in a row not taken: "
            "the model no longer describes the machine"
            for axis in disagreeing
        ),
    ]
