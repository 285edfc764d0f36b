"""Which probes reach the update (compd.service.loop.probegate): each once, one per axis per probe gap."""

from __future__ import annotations

import math

from structlog.testing import capture_logs

from compd.service.loop.probegate import DEFAULT_MIN_GAP_S, ProbeGate
from compd.service.loop.probemessages import ProbeRequest, ProbeTaken

SHA = "a" * 64
T0 = 1.8e9


def request(touched_s: float, measured_um: float = 3.0, source: str = "cli") -> ProbeRequest:
    return ProbeRequest("Z", measured_um, touched_s, source)


def taken(req: ProbeRequest) -> ProbeTaken:
    """What the loop did with a probe it gave to the update (here: refused by it, for brevity)."""
    return ProbeTaken(req, SHA, "disp_z_um", 1.0, math.nan, refused="older than the rows kept")


def test_a_resend_of_a_probe_taken_is_answered_with_what_it_did_the_first_time() -> None:
    """Same axis, source, touch and value: not given to the update; the answer carries the original."""
    gate = ProbeGate()
    first = taken(request(T0))
    gate.remember(first)
    answer = gate.screen(request(T0), SHA, "disp_z_um", last_touch_s=None)
    assert answer is not None and answer.result == "duplicate" and answer.original is first
    details = answer.event_details()
    assert details["result"] == "duplicate" and details["original_result"] == "refused"
    assert "already taken" in details["reason"] and "not taken again" in details["reason"]


def test_another_source_or_value_is_another_probe() -> None:
    """A different value, or the same value from another station, is not a resend."""
    gate = ProbeGate(min_gap_s=0.0)
    gate.remember(taken(request(T0)))
    assert gate.screen(request(T0, 3.5), SHA, "disp_z_um", None) is None
    assert gate.screen(request(T0, source="mqtt:cmm-2"), SHA, "disp_z_um", None) is None


def test_one_probe_per_axis_per_gap_of_touch_time() -> None:
    """Within 900 s of the last touch given to the update: too soon, saying why; at 900 s: given."""
    gate = ProbeGate()
    answer = gate.screen(request(T0 + 10), SHA, "disp_z_um", last_touch_s=T0)
    assert answer is not None and answer.result == "too_soon"
    assert answer.refused is not None and "one is taken per 900 s" in answer.refused
    assert "a confirmation needs a separate touch" in answer.refused
    assert gate.screen(request(T0 + DEFAULT_MIN_GAP_S), SHA, "disp_z_um", T0) is None


def test_a_touch_before_the_last_goes_on_to_the_update_which_judges_its_order() -> None:
    """A gauge result typed in late names its own touch: the update refuses it for its order, not the gate."""
    assert ProbeGate().screen(request(T0 - 3600), SHA, "disp_z_um", last_touch_s=T0) is None


def test_a_flood_is_logged_once_and_counted_when_a_probe_is_taken_again() -> None:
    """300 probes too soon: one WARNING, DEBUG after; the next probe taken ends the episode with the count."""
    gate = ProbeGate()
    with capture_logs() as logs:
        for k in range(300):
            gate.screen(request(T0 + 0.15 * k, 30.0), SHA, "disp_z_um", last_touch_s=T0)
        gate.remember(taken(request(T0 + 900)))
    levels = [entry["log_level"] for entry in logs]
    assert levels.count("warning") == 1 and levels.count("debug") == 299
    assert logs[-1]["log_level"] == "info" and logs[-1]["refused"] == 300


def test_a_reset_forgets_the_probes_taken() -> None:
    """After compd model probe --reset the same probe may be given again."""
    gate = ProbeGate()
    gate.remember(taken(request(T0)))
    gate.forget()
    assert gate.screen(request(T0), SHA, "disp_z_um", None) is None
