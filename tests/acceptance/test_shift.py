"""Acceptance 1: a model calibrated on the twin compensates an 8-hour shift through Modbus TCP."""

from __future__ import annotations

from pathlib import Path

from compd.files.modelfile import load_model
from tests.acceptance.conftest import (
    axis,
    compd,
    machine_doc,
    offset_steps_um,
    simulate,
    write_config,
)

#: The offset is written as int32 in 0.1 um: one count of rounding on top of the slew limit.
RESOLUTION_UM = 0.1


def test_calibrated_model_cuts_the_shifts_error_by_85_percent_over_modbus(
    calibrated_model: Path, short_dir: Path
) -> None:
    """Fit, `compd model load`, 8 h over Modbus TCP: RMS down >= 85 %, no step above the slew, heartbeat every tick."""
    doc = machine_doc(
        short_dir, calibrated_model, simulation={"scenario": "production", "hours": 8, "seed": 5}
    )
    # Every tick's I/O must succeed here: a request must not time out because CI is busy
    # (the bundled 0.3 s is for a real PLC; timeouts have their own tests).
    doc["drivers"]["plc"]["settings"]["request_timeout_s"] = 3.0
    doc["drivers"]["plc"]["timeout_s"] = 5.0
    config = write_config(short_dir, doc)
    compd("model", "load", calibrated_model, "--config", config.path)

    result = simulate(config)

    z = axis(result)
    print(f"modbus 8 h: RMS {z.rms_uncompensated_um:.2f} -> {z.rms_compensated_um:.2f} um "
          f"({z.reduction_pct:.1f} %), p-p {z.pp_uncompensated_um:.1f} -> {z.pp_compensated_um:.2f} um, "
          f"{result.wall_s:.1f} s")  # fmt: skip
    assert z.rms_uncompensated_um > 20, "the shift heats the machine noticeably"
    assert z.rms_compensated_um <= 0.15 * z.rms_uncompensated_um, z
    rate = doc["outputs"]["Z"]["max_rate_um_per_s"]
    assert offset_steps_um(result).max() <= rate * doc["period_s"] + RESOLUTION_UM
    # The config names this model already: `model load` of it leaves the config's model running.
    assert result.status["model"]["sha256"] == load_model(calibrated_model).sha256, (
        "the loaded model runs"
    )
    ticks = result.timing.ticks
    plc = result.machine.plc
    assert ticks == 8 * 3600 + 1 and result.simulated_s == 8 * 3600
    assert plc.heartbeat_changes == ticks, "a new heartbeat reached the PLC every tick"
    assert plc.heartbeat_repeats <= 1, "only the last status word at shutdown repeats it"
    assert plc.heartbeat_timeouts == 0
    assert result.status["counters"]["write_failures"] == 0
