"""The end of a simulated run on the terminal: the error per axis, the faults (the live view is ``compd.cli``'s)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from rich.table import Table

from compd.service.loop.statusview import not_assured
from compd.sim.plc.machine import AxisSummary, SimulatedMachine
from compd.sim.plc.tally import SignalTally
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


def fault_table(
    status: Mapping[str, Any], machine: SimulatedMachine, signals: SignalTally | None = None
) -> Table:
    """What went wrong during the run and how compd and the PLC saw it.

    With ``signals`` (every tick's health, :mod:`compd.sim.plc.tally`): the signal
    fault episodes of every input (held through a link outage, faulted, on a
    stand-in), per input how long, the drift flags and the stand-in time per input;
    without, the daemon's count of inputs gone faulted. Per probed axis the probes
    taken, flagged and refused.
    """
    counters = status["counters"]
    table = Table(title="faults", header_style="bold", show_header=False)
    table.add_column("what")
    table.add_column("count", justify="right")
    table.add_row("faults injected", str(len(machine.plc.faults_injected)))
    for fault in machine.plc.faults_injected:
        table.add_row(f"  {fault}", "")
    if signals is None:
        table.add_row("signal faults", str(counters["signal_faults"]))
    else:
        _signal_rows(table, signals)
    for key in ("driver_faults", "reconnects", "write_failures", "overruns"):
        table.add_row(key.replace("_", " "), str(counters[key]))
    for axis, probes in ((status.get("probes") or {}).get("axes") or {}).items():
        table.add_row(f"probes {axis}: taken / flagged / refused", _probe_counts(probes["results"]))
    _not_assured_rows(table, status)
    table.add_row("PLC: heartbeat timeouts", str(machine.plc.heartbeat_timeouts))
    table.add_row("PLC: values written", str(machine.plc.writes))
    return table


def _signal_rows(table: Table, signals: SignalTally) -> None:
    """The episodes (all inputs, then each with how long in which state), drift flags, stand-in time."""
    table.add_row("signal fault episodes (held, faulted or on a stand-in)", str(signals.episodes))
    for name, t in signals.inputs.items():
        if not t.episodes:
            continue
        spent = [
            f"{what} {seconds:.0f} s"
            for what, seconds in (
                ("held", t.held_s),
                ("faulted", t.faulted_s),
                ("stand-in", t.stand_in_s),
            )
            if seconds > 0
        ]
        table.add_row(f"  {name}: {', '.join(spent)}", str(t.episodes))
    table.add_row("drift flags", str(signals.drift_flags))
    stand_ins = {name: t for name, t in signals.inputs.items() if t.stand_in_episodes}
    table.add_row("stand-ins used", str(sum(t.stand_in_episodes for t in stand_ins.values())))
    for name, t in stand_ins.items():
        table.add_row(f"  stand-in time {name}", f"{t.stand_in_s:.0f} s")


def _not_assured_rows(table: Table, status: Mapping[str, Any]) -> None:
    """What compd could not assure at the end, as ``/healthz``'s warnings say it: the state not
    saved (its failed episodes), the inputs nothing verifies to an axis's tolerance, probes that
    disagree with the model. A run whose counts are all 0 is not all well without them."""
    state = status.get("state")
    if state is not None and not state["saving"]:
        table.add_row(f"state not saved ({state['error']})", str(state["failed_episodes"]))
    axes = (status.get("probes") or {}).get("axes") or {}
    for line in not_assured(
        status.get("unverifiable") or [],
        disagreeing=[axis for axis, probes in axes.items() if probes["disagrees"]],
        also=[],
    ):
        table.add_row(line, "")


def _probe_counts(results: Mapping[str, int]) -> str:
    """``4 / 1 / 2``: taken (accepted or confirmed), flagged, refused (refused, rejected, too soon, resent)."""
    taken = results.get("accepted", 0) + results.get("confirmed", 0)
    flagged = results.get("flagged", 0)
    refused = sum(results.values()) - taken - flagged
    return f"{taken} / {flagged} / {refused}"
