"""Acceptance (issue 41, item 9): a simulated run records what the axis is really off by, and a drift drifts.

The bundled simulated machine and model, a short production shift with the
spindle sensor drifting (``simulation.faults`` kind ``drift``): the recording
carries ``sim.residue.Z_um``, the twin's true thermal error plus the offset
applied, tick by tick, so a run's silent time can be counted from the file
alone; and the sensor read departs from the truth at the rate asked.
"""

from __future__ import annotations

import csv
from pathlib import Path

import pytest
from pydantic import ValidationError

from compd.files.yamlplace import resolve_path
from compd.service.daemon import Service
from compd.service.loop.compensator import TickRecord
from compd.sim.plc.machine import SimulatedMachine
from compd.sim.plc.settings import SimFaultDoc
from tests.acceptance.conftest import machine_doc, simulate, write_config

MODEL = resolve_path("bundled:simulated_model.yaml", Path("."))
DRIFT_AT_S = 600.0
RATE_PER_H = 6.0
HOURS = 0.5


def recorded_rows(records: Path) -> list[dict[str, str]]:
    """Every row of the run's CSV recordings (comment lines left out)."""
    rows: list[dict[str, str]] = []
    for path in sorted(records.rglob("*.csv")):
        lines = [line for line in path.read_text().splitlines() if not line.startswith("#")]
        rows += list(csv.DictReader(lines))
    return rows


def test_a_simulated_recording_has_the_true_residue_and_a_drift_ramps(short_dir: Path) -> None:
    """``sim.residue.Z_um`` is true error + applied offset each tick; a drift reads rate x time off the truth."""
    drift = {
        "kind": "drift", "signal": "T_spindle_degC", "rate_per_h": RATE_PER_H,
        "at_s": DRIFT_AT_S, "duration_s": 900,
    }  # fmt: skip
    doc = machine_doc(
        short_dir,
        MODEL,
        simulation={"scenario": "production", "hours": HOURS, "seed": 1, "faults": [drift]},
    )
    config = write_config(short_dir, doc)
    truth: dict[float, float] = {}
    departure: dict[float, float] = {}

    def keep(service: Service, machine: SimulatedMachine, record: TickRecord) -> None:
        truth[record.t_s] = machine.truth_now()["Z"][2]
        departure[record.t_s] = record.read["T_spindle_degC"] - machine.row["T_spindle_degC"]

    simulate(config, on_tick=keep)

    rows = recorded_rows(short_dir / "records")
    assert rows and all("sim.residue.Z_um" in row for row in rows)
    for row in rows:
        assert float(row["sim.residue.Z_um"]) == pytest.approx(truth[float(row["t_s"])], abs=1e-6)
    for t_s, off in departure.items():
        expected = RATE_PER_H * (t_s - DRIFT_AT_S) / 3600 if DRIFT_AT_S <= t_s < 1500 else 0.0
        assert off == pytest.approx(expected, abs=0.006), t_s  # the register's 0.01 degC


def test_a_drift_needs_its_rate_and_only_a_drift_takes_one() -> None:
    """``rate_per_h`` is required for ``drift`` and refused on any other kind, naming the key."""
    with pytest.raises(ValidationError, match="rate_per_h"):
        SimFaultDoc(kind="drift", signal="T_degC", at_s=0, duration_s=60)
    with pytest.raises(ValidationError, match="rate_per_h"):
        SimFaultDoc(kind="offset", signal="T_degC", at_s=0, duration_s=60, value=1, rate_per_h=1)
    assert SimFaultDoc(kind="drift", signal="T_degC", at_s=0, duration_s=60, rate_per_h=-0.5)
