"""Acceptance (issue 41, item 5): an offset held at the clamp is a fault within minutes, never status OK.

The bundled simulated machine and model, a production shift (seed 1) in which
two sensors fail together at 2 h (the spindle reads 15 degC high, the
headstock 25 degC low), the case that left the offset at the +150 um clamp
with no alert to the end of the shift. compd runs unchanged on virtual time.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from structlog.testing import capture_logs

from compd.files.yamlplace import resolve_path
from compd.service.daemon import Service
from compd.service.loop.compensator import TickRecord
from compd.service.loop.safety import Level
from compd.sim.plc.machine import SimulatedMachine
from tests.acceptance.conftest import machine_doc, simulate, write_config

MODEL = resolve_path("bundled:simulated_model.yaml", Path("."))
AT_S = 7200.0
#: ``safety.envelope_after_s``'s default.
AFTER_S = 300.0
FAULTS = [
    {"kind": "offset", "signal": "T_spindle_degC", "value": 15, "at_s": AT_S, "duration_s": 3600},
    {
        "kind": "offset",
        "signal": "T_headstock_degC",
        "value": -25,
        "at_s": AT_S,
        "duration_s": 3600,
    },
]


def test_two_sensors_failing_together_fault_the_status_within_minutes_of_the_clamp(short_dir):
    """Once the target has sat at the clamp (or beyond the calibration) 300 s the status is faulted, one ERROR."""
    doc = machine_doc(
        short_dir,
        MODEL,
        simulation={"scenario": "production", "hours": 2.75, "seed": 1, "faults": FAULTS},
    )
    doc["recorder"] = {"enabled": False}
    config = write_config(short_dir, doc)
    records: list[TickRecord] = []

    def keep(service: Service, machine: SimulatedMachine, record: TickRecord) -> None:
        records.append(record)

    with capture_logs() as logs:
        result = simulate(config, on_tick=keep)
    at_clamp = [r for r in records if abs(r.offsets_um["Z"]) >= 150.0]
    assert at_clamp, "the two faults drive the offset to the clamp"
    first_out = next(r.t_s for r in records if "Z" in r.outside_envelope)
    assert first_out <= at_clamp[0].t_s
    faulted = [r for r in records if r.status & 0b11 == Level.FAULTED]
    assert faulted and faulted[0].t_s == first_out + AFTER_S  # minutes, not the rest of the shift
    for record in records:  # never OK while the target has been outside longer than that
        said: Any = record.outside_envelope.get("Z", "")
        if "faulted" in said:
            assert record.status & 0b11 == Level.FAULTED
    assert not any(
        r.offsets_um["Z"] >= 150.0 for r in records if r.t_s > faulted[0].t_s + 60.0 + 150.0
    )
    started = [e for e in logs if e["event"].startswith("offset outside its envelope")]
    assert len(started) == 1 and started[0]["axis"] == "Z"
    assert result.status["counters"]["envelope_faults"] == 1
