"""What the probes taught survives a restart, and what belongs to a warm shift does not (issue 42).

The long-nose machine (its Z drift about 1.7 times the bundled model's) runs a
production shift with a probe cycle whenever compd says one is due; the
probes teach the update mostly a shift. The daemon stops; the machine stands
and is cold when it starts again, its state directory kept. A simulation's
clock runs ahead of the wall, so the first shift's probe times lie in the
future of the second start: the clock a clock change would leave.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from compd.sim.plc.run import SimulationResult
from tests.acceptance.conftest import machine_doc, simulate, write_config
from tests.acceptance.test_probes import MODEL, PERIOD_S, PROBES


def shift(folder: Path, state: Path, seed: int, probes: bool, hours: float) -> SimulationResult:
    """A production shift on the long-nose machine, from cold, the state kept in ``state``."""
    folder.mkdir(parents=True, exist_ok=True)
    simulation: dict[str, Any] = {
        "scenario": "production",
        "variant": "long-nose",
        "hours": hours,
        "seed": seed,
        "sample_time_s": PERIOD_S,
        "stop_at_end": True,
    }
    if probes:
        simulation["probes"] = {"when_due": True}
    doc = machine_doc(folder, MODEL, simulation=simulation, period_s=PERIOD_S, probes=PROBES)
    doc["state"]["directory"] = str(state)
    doc["outputs"]["Z"]["max_offset_um"] = 200  # the variant's drift exceeds the bundled 150
    doc["recorder"] = {"enabled": False}
    return simulate(write_config(folder, doc))


@pytest.fixture(scope="module")
def restarted(
    tmp_path_factory: pytest.TempPathFactory,
) -> tuple[SimulationResult, SimulationResult, SimulationResult]:
    """The probed shift, the next shift on the same state directory, and that shift never probed."""
    tmp = tmp_path_factory.mktemp("restart")
    first = shift(tmp / "first", tmp / "state", seed=1, probes=True, hours=4.5)
    second = shift(tmp / "second", tmp / "state", seed=2, probes=True, hours=2.5)
    unprobed = shift(tmp / "open", tmp / "open-state", seed=2, probes=False, hours=1.0)
    return first, second, unprobed


def rms_um(result: SimulationResult, hours: float) -> float:
    machine = result.machine
    k = min(machine.k + 1, int(hours * 3600 / PERIOD_S))
    error = (machine.true_um + machine.offset_um)[:k, 2]
    return float(np.sqrt(np.mean(error**2)))


def test_the_first_hour_after_a_cold_restart_is_no_worse_than_the_calibrated_model(
    restarted: tuple[SimulationResult, SimulationResult, SimulationResult],
) -> None:
    """The first shift's learned shift is set back at the cold start: the first hour as open loop, or better."""
    first, second, unprobed = restarted
    assert len(first.machine.probe_cycles) >= 2
    assert rms_um(second, 1.0) <= rms_um(unprobed, 1.0) + 0.05, (
        rms_um(second, 1.0),
        rms_um(unprobed, 1.0),
    )


def test_probes_fall_due_in_the_shift_after_a_restart(
    restarted: tuple[SimulationResult, SimulationResult, SimulationResult],
) -> None:
    """The first shift's probe times lay ahead of the second start's clock: clamped, so the first probe
    is due 2 h after the start."""
    _, second, _ = restarted
    touched_h = [c.touched_s / 3600.0 for c in second.machine.probe_cycles]
    assert touched_h and touched_h[0] <= 2.2, touched_h
