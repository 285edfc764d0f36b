"""The model learns from the machine (issue 35): the bundled model meets a programme it was not calibrated for.

The simulated machine is the long-nose spindle variant (its Z drift about 1.7
times what the bundled model predicts) on the production programme. Its PLC
runs a probe cycle when compd's probe status word says one is due (every 2 h),
writing what the probe measured (the residue on the datum, with 0.5 um of
noise) through the Modbus registers of ``probes.axes.Z``; compd takes each
count once, updates the model and echoes the count. Judged as a shop would:
the error left on the parts, with probes and without, on the same machine.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from compd.files.yamlplace import resolve_path
from compd.sim.plc.run import SimulationResult
from tests.acceptance.conftest import machine_doc, simulate, write_config

MODEL = resolve_path("bundled:simulated_model.yaml", Path("."))
HOURS = 8.0
PERIOD_S = 10.0  # the bundled model's own sample time: the shift in 2,880 ticks
PROBES = {
    "every_h": 2,
    "axes": {
        "Z": {
            "driver": "plc",
            "value_address": "holding:120:int32",
            "value_scale": 0.1,
            "counter_address": "holding:122",
            "echo_address": "holding:123",
            "status_address": "holding:124",
            "touched_at_address": "holding:125:uint32",
        }
    },
}


def shift(tmp_path: Path, probes: dict[str, Any] | None, **kwargs: Any) -> SimulationResult:
    """The long-nose machine's production shift with the bundled model; probe cycles when due."""
    tmp_path.mkdir(parents=True, exist_ok=True)
    simulation: dict[str, Any] = {
        "scenario": "production",
        "variant": "long-nose",
        "hours": HOURS,
        "seed": 1,
        "sample_time_s": PERIOD_S,
        "stop_at_end": True,
    }
    if probes is not None:
        simulation["probes"] = probes
    doc = machine_doc(tmp_path, MODEL, simulation=simulation, period_s=PERIOD_S, probes=PROBES)
    doc["outputs"]["Z"]["max_offset_um"] = 200  # the variant's drift exceeds the bundled 150
    doc["recorder"] = {"enabled": False}
    return simulate(write_config(tmp_path, doc), **kwargs)


@pytest.fixture(scope="module")
def shifts(tmp_path_factory: pytest.TempPathFactory) -> tuple[SimulationResult, SimulationResult]:
    """The same shift: the PLC never probing, and probing when compd says a probe is due."""
    tmp = tmp_path_factory.mktemp("probes")
    return shift(tmp / "open", None), shift(tmp / "probed", {"when_due": True})


def rms_um(result: SimulationResult) -> float:
    machine = result.machine
    error = (machine.true_um + machine.offset_um)[: machine.k + 1, 2]
    return float(np.sqrt(np.mean(error**2)))


def test_probes_every_2_h_halve_the_error_left_on_the_parts(
    shifts: tuple[SimulationResult, SimulationResult],
) -> None:
    open_loop, probed = shifts
    cycles = probed.machine.probe_cycles
    assert len(cycles) >= 3, [c.touched_s for c in cycles]
    assert rms_um(probed) <= 0.5 * rms_um(open_loop), (rms_um(probed), rms_um(open_loop))


def test_each_probe_cycle_is_taken_once_and_echoed(
    shifts: tuple[SimulationResult, SimulationResult],
) -> None:
    _, probed = shifts
    station = probed.machine.probe_stations["Z"]
    cycles = probed.machine.probe_cycles
    assert station.log.echo == cycles[-1].count  # compd took the last count the PLC wrote
    z = probed.status["probes"]["axes"]["Z"]
    assert z["probes"] == len(cycles), z
    assert "refused" not in z["results"], z["results"]


def test_a_misprobe_of_50_um_is_flagged_and_changes_no_offset(tmp_path: Path) -> None:
    """A chip on the datum ball at 5 h: flagged, the parameters (so every offset) as before it;
    the probe is still due, the PLC probes again, and that probe rejects the flagged one."""
    taken: list[tuple[Any, np.ndarray, np.ndarray]] = []
    before: list[np.ndarray] = []

    def on_tick(service: Any, machine: Any, record: Any) -> None:
        theta = service.probing.learners["disp_z_um"].theta.copy()
        for probe in record.probes:
            taken.append((probe, before[-1], theta))
        before.append(theta)

    misprobe = {"when_due": True, "misprobes": [{"at_s": 5 * 3600, "error_um": 50.0}]}
    result = shift(tmp_path, misprobe, on_tick=on_tick)
    cycle = next(c for c in result.machine.probe_cycles if c.misprobe_um)
    chip = [
        (p, b, a)
        for p, b, a in taken
        if abs(p.request.touched_at_unix_s - cycle.touched_at_unix_s) < 1.0
    ]
    assert [p.result for p, _, _ in chip] == ["flagged"]
    _, theta_before, theta_after = chip[0]
    np.testing.assert_array_equal(theta_after, theta_before)  # so every offset as without it
    following = [c for c in result.machine.probe_cycles if c.touched_s > cycle.touched_s]
    assert following and following[0].touched_s - cycle.touched_s <= 0.5 * 3600  # due again
    assert result.status["probes"]["axes"]["Z"]["results"].get("rejected") == 1
