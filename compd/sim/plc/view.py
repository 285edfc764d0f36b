"""The end of a simulated run on the terminal: the error per axis, the faults (the live view is ``compd.cli``'s)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from rich.table import Table

from compd.sim.plc.machine import AxisSummary, SimulatedMachine
from compd.toolkit.summary import fmt


def summary_table(rows: list[AxisSummary], *, narrow: bool = False) -> Table:
    """Uncompensated vs compensated RMS, peak-to-peak and max |error| per axis.

    ``narrow``: each title in two lines (80 columns), so none is cut.
    """
    table = Table(title="thermal error at the tool centre point, um", header_style="bold")
    table.add_column("axis")
    between = "\n" if narrow else " "
    for name in ("RMS", "p-p", "max |e|"):
        table.add_column(f"{name}{between}uncomp.", justify="right")
        table.add_column(f"{name}{between}comp.", justify="right")
    table.add_column(f"RMS{between}reduction", justify="right")
    for r in rows:
        table.add_row(
            r.axis,
            fmt(r.rms_uncompensated_um),
            fmt(r.rms_compensated_um),
            fmt(r.pp_uncompensated_um),
            fmt(r.pp_compensated_um),
            fmt(r.max_uncompensated_um),
            fmt(r.max_compensated_um),
            f"{fmt(r.reduction_pct, 1)} %",
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
