"""The daemon and its envelope: an axis asking beyond its calibration for minutes is a fault everyone sees."""

from __future__ import annotations

import asyncio
from pathlib import Path

from structlog.testing import capture_logs

from compd.faultlog import Event
from compd.files.yamlplace import resolve_path
from compd.service.daemon import Service
from compd.service.http.history import RecentFaults
from compd.service.loop.clock import VirtualClock
from compd.service.loop.compensator import TickRecord
from compd.service.loop.safety import Level, model_fault_bit
from compd.service.loop.statusview import health_problems

from .daemon_setup import write_config

#: The replayed test drives disp_y_um down to about -0.36 um from 7200 s on (offset +0.36 um).
CALIBRATED = "  calibration: {data: x.csv, samples: 28800, sample_time_s: 1.0, ranges: {disp_y_um: [-0.25, 0.1]}}\n"
AFTER_S = 120


def calibrated_model(directory: Path) -> Path:
    """The bundled example model, with a calibration record whose output range it leaves for a while."""
    text = resolve_path("bundled:example_gated_arx.yaml", Path(".")).read_text()
    path = directory / "calibrated.yaml"
    path.write_text(text + CALIBRATED)
    return path


def test_a_target_beyond_the_calibration_faults_the_status_once_and_says_so_everywhere(tmp_path):
    """Outside its band 120 s on end: level faulted, the model-fault bit, an ERROR then an INFO, counter, status."""
    config = write_config(
        tmp_path,
        {
            "model": str(calibrated_model(tmp_path)),
            "drivers": {"machine": {"settings": {"start_s": 7200}}},
            "safety": {"envelope_after_s": AFTER_S},
        },
    )
    service = Service(config, clock=VirtualClock(), control=False)
    records: list[TickRecord] = []
    problems: list[list[str]] = []
    statuses: list[dict] = []
    page = RecentFaults()

    def keep(record: TickRecord) -> None:
        records.append(record)
        page.update(record, service.compensator, service.links)
        if "faulted" in record.outside_envelope.get("Y", "") and not statuses:
            comp = service.compensator
            statuses.append(service.status())
            problems.append(
                health_problems(
                    comp, service.links, service.timing, clock=service.clock, period_s=1.0
                )
            )

    service.subscribe(keep)
    events: list[Event] = []
    service.compensator.report_to(events.append)  # as the telemetry is told
    with capture_logs() as logs:
        asyncio.run(service.run(duration_s=1400))
    outside = [r for r in records if "Y" in r.outside_envelope]
    faulted = [r for r in outside if "faulted" in r.outside_envelope["Y"]]
    assert outside and faulted and faulted[-1] is not records[-1]  # it began, and it ended
    assert faulted[0].t_s - outside[0].t_s == AFTER_S
    bit = 1 << (model_fault_bit(len(records[0].health)) or 0)
    for record in records:
        is_faulted = record in faulted
        assert (record.status & 0b11 == Level.FAULTED) is is_faulted
        assert bool(record.status & bit) is is_faulted
    said = faulted[0].outside_envelope["Y"]
    assert said.startswith("Y asks beyond its calibration: target +0.")
    assert said.endswith("faulted, the offset ramps to 0 after 60 s (safety.on_fault: ramp)")
    episode = [e for e in logs if e.get("axis") == "Y" and "envelope" in e["event"]]
    assert [(e["log_level"], e["event"]) for e in episode] == [
        (
            "error",
            "offset outside its envelope: the model is not trusted, the axis follows on_fault",
        ),
        ("info", "offset back inside its envelope"),
    ]
    told = [(e.kind, e.details["axis"]) for e in events if "envelope" in e.message]
    assert told == [("fault", "Y"), ("cleared", "Y")]
    assert service.status()["counters"]["envelope_faults"] == 1
    envelope = statuses[0]["envelope"]["Y"]
    assert envelope["faulted"] and envelope["outside"] == said
    assert envelope["envelope"] == "clamp ±50 um, calibrated -0.2..+0.3 um"
    assert any(p.startswith("envelope: Y asks beyond its calibration") for p in problems[0])
    listed = [e for e in page.events if e.kind == "envelope"]
    assert [(e.source, e.message) for e in listed] == [("Y", said)]  # the page's last faults
