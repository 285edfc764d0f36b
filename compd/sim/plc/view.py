"""The terminal view of a simulated run: live inputs, model, offsets and true errors; a summary at the end."""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any

from rich.console import Group
from rich.table import Table
from rich.text import Text

from compd.service.compensator import TickRecord
from compd.service.safety import Level
from compd.service.signals import Health
from compd.sim.plc.machine import AxisSummary, SimulatedMachine

_HEALTH_STYLE = {Health.OK: "green", Health.HELD: "yellow", Health.FAULTED: "bold red"}
_LEVEL_STYLE = {Level.OK: "green", Level.DEGRADED: "yellow", Level.FAULTED: "bold red"}

#: The axis table's columns: each says which quantity, and which sign, it shows.
AXIS_COLUMNS = (
    "axis",
    "model drift um",
    "sign",
    "offset written um (sign x drift, limited)",
    "true error um",
    "compensated um",
)


def live_view(
    machine: SimulatedMachine,
    record: TickRecord,
    units: Mapping[str, str],
    counters: Mapping[str, int],
    started_wall_s: float,
    *,
    signs: Mapping[str, int],
    duration_s: float,
) -> Group:
    """One frame: where the run is, every input with its health, every axis with its true error.

    ``duration_s`` is where the run ends (the scenario's end, or ``--duration-s``);
    ``signs`` the outputs' ``sign``: the offset written is ``sign x`` the model's drift.
    """
    level = Level(record.status & 0b11)
    elapsed = max(time.perf_counter() - started_wall_s, 1e-9)
    done_pct = 100.0 * min(machine.now_s / duration_s, 1.0) if duration_s > 0 else 100.0
    head = Text.assemble(
        ("simulated machine ", "bold"),
        f"{machine.doc.scenario} (seed {machine.doc.seed})  ",
        f"t {_hms(machine.now_s)} / {_hms(duration_s)} ({done_pct:.0f} %)  ",
        f"x{machine.now_s / elapsed:,.0f} real time  status ",
        (level.name.lower(), _LEVEL_STYLE[level]),
    )
    inputs = Table(box=None, pad_edge=False, header_style="bold")
    inputs.add_column("input")
    inputs.add_column("value", justify="right")
    inputs.add_column("health")
    for name, value in record.values.items():
        health = record.health[name]
        reason = record.reasons.get(name, "")
        inputs.add_row(
            name,
            f"{value:.3f} {units.get(name, '')}",
            Text(health.name.lower() + (f" ({reason})" if reason else ""), _HEALTH_STYLE[health]),
        )
    axes = Table(box=None, pad_edge=False, header_style="bold")
    axes.add_column("axis")
    for column in AXIS_COLUMNS[1:]:
        axes.add_column(column, justify="right")
    truth = machine.truth_now()
    for axis, (true_um, _, comp_um) in truth.items():
        sign = signs.get(axis, 1)
        # The record's target is sign x the model's output: the model's own drift is target x sign.
        drift_um = record.targets_um.get(axis, float("nan")) * sign
        axes.add_row(
            axis,
            f"{drift_um:+.2f}",
            f"{sign:+d}",
            f"{record.offsets_um.get(axis, float('nan')):+.2f}",
            f"{true_um:+.2f}",
            f"{comp_um:+.2f}",
        )
    counts = ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in counters.items())
    return Group(head, inputs, axes, Text(counts, "dim"))


def summary_table(rows: list[AxisSummary]) -> Table:
    """Uncompensated vs compensated RMS, peak-to-peak and max |error| per axis."""
    table = Table(title="thermal error at the tool centre point, um", header_style="bold")
    table.add_column("axis")
    for name in ("RMS", "p-p", "max |e|"):
        table.add_column(f"{name} uncomp.", justify="right")
        table.add_column(f"{name} comp.", justify="right")
    table.add_column("RMS reduction", justify="right")
    for r in rows:
        table.add_row(
            r.axis,
            f"{r.rms_uncompensated_um:.2f}",
            f"{r.rms_compensated_um:.2f}",
            f"{r.pp_uncompensated_um:.2f}",
            f"{r.pp_compensated_um:.2f}",
            f"{r.max_uncompensated_um:.2f}",
            f"{r.max_compensated_um:.2f}",
            f"{r.reduction_pct:.1f} %",
        )
    return table


def fault_table(status: Mapping[str, Any], machine: SimulatedMachine) -> Table:
    """What went wrong during the run and how compd and the PLC saw it."""
    counters = status["counters"]
    table = Table(title="faults", header_style="bold", show_header=False)
    table.add_column("what")
    table.add_column("count", justify="right")
    table.add_row("faults injected", str(len(machine.plc.faults_injected)))
    for fault in machine.plc.faults_injected:
        table.add_row(f"  {fault}", "")
    for key in ("signal_faults", "driver_faults", "reconnects", "write_failures", "overruns"):
        table.add_row(key.replace("_", " "), str(counters[key]))
    table.add_row("PLC: heartbeat timeouts", str(machine.plc.heartbeat_timeouts))
    table.add_row("PLC: values written", str(machine.plc.writes))
    return table


def _hms(seconds: float) -> str:
    s = int(seconds)
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}"
