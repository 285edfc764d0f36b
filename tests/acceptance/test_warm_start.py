"""Acceptance: compd started on a machine that is already warm, with no saved state, compensates at once.

A shop installs compd on a running machine, and a power cut loses the state
file: either way the daemon starts mid-shift. The model fitted by ``compd fit``
carries its calibration's thermal zero (absolute input references), so the
daemon starts each sub-model at the steady state for the current inputs
relative to that zero and ramps the offset in under the slew limit, instead
of taking the warm machine as its zero ("value at start").
"""

from __future__ import annotations

from pathlib import Path

import pytest

from compd.errors import ConfigFileError
from compd.files.modelfile import load_model
from compd.sim.plc.build import build_machine
from tests.acceptance.conftest import axis, machine_doc, offset_steps_um, simulate, write_config

#: The offset is written as int32 in 0.1 um: one count of rounding on top of the slew limit.
RESOLUTION_UM = 0.1


@pytest.mark.parametrize("join_h", [0.5, 2.0])
def test_compd_started_mid_shift_without_state_cuts_the_rest_of_the_shifts_error_by_90_percent(
    calibrated_model: Path, short_dir: Path, join_h: float
) -> None:
    """compd joins the simulated machine 0.5 h / 2 h into a shift (no state file): RMS down >= 90 % over the rest."""
    references = [
        sub.input.reference
        for output in load_model(calibrated_model).model.outputs
        for sub in output.submodels
    ]
    assert None not in references, "compd fit writes absolute references, not 'start'"
    doc = machine_doc(
        short_dir,
        calibrated_model,
        simulation={"scenario": "production", "hours": 8, "seed": 1, "join_at_s": join_h * 3600},
    )
    doc["drivers"]["plc"]["settings"]["request_timeout_s"] = 3.0
    doc["drivers"]["plc"]["timeout_s"] = 5.0
    config = write_config(short_dir, doc)
    assert not (config.state_dir / "state.json").exists()

    result = simulate(config)

    z = axis(result)
    print(f"joined at {join_h} h: RMS {z.rms_uncompensated_um:.2f} -> {z.rms_compensated_um:.2f} um "
          f"({z.reduction_pct:.1f} %), p-p {z.pp_uncompensated_um:.1f} -> {z.pp_compensated_um:.2f} um, "
          f"{result.wall_s:.1f} s")  # fmt: skip
    assert result.timing.ticks == round((8 - join_h) * 3600) + 1, "compd ran the rest of the shift"
    assert z.rms_uncompensated_um > 30, "the machine was warm when compd joined"
    assert z.reduction_pct >= 90.0, z
    rate = doc["outputs"]["Z"]["max_rate_um_per_s"]
    assert offset_steps_um(result).max() <= rate * doc["period_s"] + RESOLUTION_UM, (
        "the drift before the start is ramped in under the slew limit"
    )
    initialised = result.status["model"]["initialised"]
    assert "steady state for the current inputs" in initialised and "thermal zero" in initialised


def test_a_join_time_past_the_scenarios_end_is_refused(
    calibrated_model: Path, short_dir: Path
) -> None:
    """simulation.join_at_s beyond the scenario's length is a config error naming the key."""
    doc = machine_doc(short_dir, calibrated_model, simulation={"hours": 1, "join_at_s": 3600})
    config = write_config(short_dir, doc)

    with pytest.raises(ConfigFileError, match="join_at_s"):
        build_machine(config)
