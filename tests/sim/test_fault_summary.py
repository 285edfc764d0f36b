"""The end of a simulated run counts what its inputs went through: a link outage, stand-ins, probes.

The daemon's ``signal_faults`` counts inputs gone faulted; the summary ``compd run``
prints at the end counts every input's episodes away from ``ok`` (held through
an outage, faulted, on a stand-in), the time on a stand-in per input, and per
probed axis the probes taken, flagged and refused.
"""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

import pytest
import yaml
from rich.console import Console

from compd.service.config.loading import load_config
from compd.service.loop.compensator import TickRecord
from compd.service.loop.signals import Health
from compd.sim.plc.run import SimulationResult, run_simulation
from compd.sim.plc.tally import SignalTally
from compd.sim.plc.view import fault_table
from tests.ports import free_port
from tests.sim.test_plc_probes import MODEL, PROBE_REGISTERS, SIMULATED

OUTAGE_S = (300, 60)  # the PLC drops off the network at 300 s for 60 s
NAN_S = (700, 120)  # the spindle sensor reads NaN: its partner stands in


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> SimulationResult:
    """20 min of the bundled simulated machine with an outage, a sensor's NaN, probes every 6 min."""
    tmp_path = tmp_path_factory.mktemp("faultsummary")
    doc: dict[str, Any] = yaml.safe_load(SIMULATED.read_text())
    doc["model"] = str(MODEL)
    doc["drivers"]["plc"]["settings"]["port"] = free_port()
    doc["state"] = {"directory": str(tmp_path / "state")}
    doc["recorder"] = {"enabled": False}
    doc["probes"] = {"every_h": 0.1, "axes": {"Z": PROBE_REGISTERS}}
    doc["simulation"] = {
        "scenario": "production",
        "hours": 8,
        "seed": 1,
        "probes": {"when_due": True, "min_gap_h": 0.05},
        "faults": [
            {"kind": "drop", "driver": "plc", "at_s": OUTAGE_S[0], "duration_s": OUTAGE_S[1]},
            {"kind": "nan", "signal": "T_spindle_degC", "at_s": NAN_S[0], "duration_s": NAN_S[1]},
        ],
    }
    path = tmp_path / "compd.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return asyncio.run(run_simulation(load_config(path), duration_s=1200))


def shown(run: SimulationResult) -> dict[str, str]:
    """The fault table as ``compd run`` prints it, row title (indent stripped) -> count."""
    out = Console(width=200, record=True, force_terminal=False)
    out.print(fault_table(run.status, run.machine, run.signals))
    rows = {}
    for line in out.export_text().splitlines():
        cells = [c.strip() for c in line.strip("│").split("│")]
        if len(cells) == 2:
            rows[cells[0]] = cells[1]
    return rows


def test_every_input_held_through_the_outage_is_an_episode(run: SimulationResult) -> None:
    """Each input the outage left without readings counts once, whether it was held or went faulted."""
    rows = shown(run)
    assert run.signals is not None
    names = list(run.status["inputs"])
    assert all(run.signals.inputs[n].episodes >= 1 for n in names)
    assert int(rows["signal fault episodes (held, faulted or on a stand-in)"]) >= len(names)
    assert any(title.startswith("T_headstock_degC: held") for title in rows), rows


def test_the_stand_in_time_is_a_row_per_input(run: SimulationResult) -> None:
    """The spindle sensor's NaN is bridged by its partner: a stand-in used, and its time in seconds."""
    rows = shown(run)
    assert run.signals is not None
    spindle = run.signals.inputs["T_spindle_degC"]
    assert spindle.stand_in_episodes >= 1 and spindle.stand_in_s >= NAN_S[1] * 0.5
    assert int(rows["stand-ins used"]) >= 1
    assert rows["stand-in time T_spindle_degC"] == f"{spindle.stand_in_s:.0f} s"
    assert rows["drift flags"] == "0"


def test_the_probes_of_each_axis_are_counted(run: SimulationResult) -> None:
    """Per probed axis: taken / flagged / refused, as the daemon's results count them."""
    rows = shown(run)
    results = run.status["probes"]["axes"]["Z"]["results"]
    taken, flagged, refused = (
        int(n) for n in rows["probes Z: taken / flagged / refused"].split(" / ")
    )
    assert taken + flagged + refused == sum(results.values()) >= 2
    assert taken == results.get("accepted", 0) + results.get("confirmed", 0)


def test_an_episode_lasts_until_the_input_is_ok_again() -> None:
    """Held then faulted then on a stand-in is one episode; its seconds are summed per state."""
    tally = SignalTally(period_s=1.0)
    healths = [Health.OK, Health.HELD, Health.FAULTED, Health.ESTIMATED, Health.OK, Health.HELD]
    for t_s, health in enumerate(healths):
        tally.observe(record(t_s, health))
    spindle = tally.inputs["T_spindle_degC"]
    assert (spindle.episodes, spindle.faulted_episodes, spindle.stand_in_episodes) == (2, 1, 1)
    assert (spindle.held_s, spindle.faulted_s, spindle.stand_in_s) == (2.0, 1.0, 1.0)
    assert tally.episodes == 2 and tally.drift_flags == 0


def record(t_s: float, health: Health) -> TickRecord:
    """A tick in which only the spindle sensor is read, with ``health``."""
    return TickRecord(
        t_s=t_s,
        wall_unix_s=t_s,
        values={"T_spindle_degC": 20.0},
        health={"T_spindle_degC": health},
        reasons={},
        model_outputs={},
        contributions={},
        targets_um={},
        offsets_um={},
        status=0,
        heartbeat=0,
        written=True,
    )


def test_the_summary_says_what_compd_could_not_assure(tmp_path: Path) -> None:
    """The spindle on one sensor (its second taken away) and a state directory that refuses every
    save: the summary has a row for each, not only counts of 0."""
    doc: dict[str, Any] = yaml.safe_load(SIMULATED.read_text())
    doc["model"] = str(MODEL)
    doc["drivers"]["plc"]["settings"]["port"] = free_port()
    doc["signals"]["T_spindle_degC"].pop("redundant")
    doc["state"] = {"directory": str(tmp_path / "state"), "save_every_ticks": 10}
    doc["recorder"] = {"enabled": False}
    doc["simulation"] = {"scenario": "production", "hours": 1, "seed": 1}
    path = tmp_path / "compd.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    state_file = tmp_path / "state" / "state.json"

    def break_state(*_: object) -> None:
        if not state_file.is_dir():  # a save's rename cannot replace a directory
            state_file.unlink(missing_ok=True)
            state_file.mkdir(parents=True)

    result = asyncio.run(run_simulation(load_config(path), duration_s=60, on_tick=break_state))
    rows = shown(result)
    assert any(title.startswith("state not saved ([Errno 21] Is a directory") for title in rows), (
        rows
    )
    assert "not assured on Z: T_spindle_degC not verifiable to its 1.56 um tolerance" in rows, rows
