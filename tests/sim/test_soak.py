"""The soak's witness (:class:`compd.sim.soakwitness.Witness`) judges what the PLC's offset register receives."""

from __future__ import annotations

import math

from compd.service.loop.compensator import TickRecord
from compd.sim.soakwitness import SoakResult, Witness

OFFSET = "holding:100:int32"


def record(acknowledged_um: float) -> TickRecord:
    return TickRecord(
        t_s=0.0, wall_unix_s=0.0, values={}, health={}, reasons={}, model_outputs={},
        contributions={}, targets_um={}, offsets_um={}, status=0, heartbeat=0,
        written=math.isfinite(acknowledged_um), acknowledged_um={"Z": acknowledged_um},
    )  # fmt: skip


def witness() -> tuple[Witness, SoakResult, list[tuple[str, float]]]:
    result, passed = SoakResult(), []
    w = Witness(OFFSET, scale=10.0, max_step_um=1.0, result=result)
    return w, result, passed


def test_a_step_beyond_the_slew_limit_from_what_the_register_held_is_counted():
    """Steps are judged from what the register held, a PLC reset included: 0 -> 1.0 ok, reset, 0 -> 1.1 counted."""
    w, result, passed = witness()
    sink = w.sink(lambda address, raw: passed.append((address, raw)))
    sink(OFFSET, 10.0)  # 1.0 um from 0: one step
    sink("holding:110", 999.0)  # the status word is not an offset
    w.programming = True
    sink(OFFSET, 0.0)  # the PLC clears its register
    w.programming = False
    sink(OFFSET, 11.0)  # 1.1 um from 0: beyond the step
    assert result.slew_violations == 1 and result.largest_step_um == 1.1
    assert result.offsets_received == 2 and len(passed) == 4  # everything reaches the machine


def test_an_acknowledged_offset_the_plc_never_received_is_counted():
    """A tick acknowledging 0.5 um counts only if 5 counts arrived during it; a failed write is no claim."""
    w, result, _ = witness()
    sink = w.sink(lambda address, raw: None)
    sink(OFFSET, 5.0)
    w.tick(record(0.5), "Z")
    w.tick(record(0.6), "Z")  # nothing arrived this tick
    sink(OFFSET, 7.0)
    w.tick(record(math.nan), "Z")  # it landed, but the service counts the write failed
    assert (result.unacknowledged, result.landed_unacknowledged, result.ticks) == (1, 1, 3)


def test_a_write_outside_the_clamp_is_counted_and_a_correction_is_no_step():
    """With a 150 um clamp: 500 um set by the PLC, then 0 written is a correction; 150.1 um written is outside."""
    result = SoakResult()
    w = Witness(OFFSET, scale=10.0, max_step_um=1.0, result=result, max_offset_um=150.0)
    sink = w.sink(lambda address, raw: None)
    w.programming = True
    sink(OFFSET, 5000.0)  # the PLC's program: 500 um
    w.programming = False
    sink(OFFSET, 0.0)  # compd replaces it: a jump, but into the clamp
    sink(OFFSET, 10.0)
    assert (result.corrections, result.slew_violations, result.outside_clamp) == (1, 0, 0)
    w.programming = True
    sink(OFFSET, 1500.0)
    w.programming = False
    sink(OFFSET, 1501.0)  # 150.1 um: a step of 0.1 um, but outside the clamp
    assert (result.outside_clamp, result.slew_violations, result.passed) == (1, 0, False)


def test_heartbeats_are_counted_apart_from_offsets():
    """Writes to the heartbeat address count as heartbeats, never as offsets or steps."""
    result = SoakResult()
    w = Witness(OFFSET, scale=10.0, max_step_um=1.0, result=result, heartbeat_address="holding:111")
    sink = w.sink(lambda address, raw: None)
    for beat in range(3):
        sink("holding:111", float(beat * 1000))
    sink(OFFSET, 5.0)
    assert (w.heartbeats, result.offsets_received, result.slew_violations) == (3, 1, 0)
