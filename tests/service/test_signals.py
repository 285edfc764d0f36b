"""Per-signal checks: range, spike, stuck, stale, hold and fault, recovery."""

from __future__ import annotations

import math

from compd.service.loop.signals import Checks, Health, SignalMonitor


def feed(monitor: SignalMonitor, values, start_s: float = 0.0):
    return [monitor.update(start_s + k, v) for k, v in enumerate(values)]


def test_good_values_pass_through():
    """Values in range without spikes are used as read."""
    readings = feed(SignalMonitor("T", Checks(min=0, max=50, max_jump=1.0)), [20.0, 20.5, 21.0])
    assert [(r.value, r.health) for r in readings] == [
        (20.0, Health.OK),
        (20.5, Health.OK),
        (21.0, Health.OK),
    ]


def test_out_of_range_is_held_then_faulted():
    """An out-of-range value is replaced by the last good one for hold_s seconds, then the signal is faulted."""
    monitor = SignalMonitor("T", Checks(min=0, max=50, hold_s=3.0))
    readings = feed(monitor, [20.0, 99.0, 99.0, 99.0, 99.0])
    assert [r.health for r in readings] == [
        Health.OK,
        Health.HELD,
        Health.HELD,
        Health.HELD,
        Health.FAULTED,
    ]
    assert {r.value for r in readings} == {20.0}
    assert "above max" in readings[1].reason


def test_nan_and_spike_are_bad():
    """NaN and a jump beyond max_jump are held; a good value ends the hold at once."""
    monitor = SignalMonitor("T", Checks(max_jump=1.0, hold_s=10.0))
    readings = feed(monitor, [20.0, math.nan, 25.0, 20.4])
    assert [r.health for r in readings] == [Health.OK, Health.HELD, Health.HELD, Health.OK]
    assert readings[2].reason.startswith("spike")
    assert readings[3].value == 20.4


def test_missing_values_are_bridged_until_stale():
    """No new value is bridged with the last one for stale_s, then counts as bad and is faulted after hold_s."""
    monitor = SignalMonitor("T", Checks(stale_s=3.0, hold_s=2.0))
    readings = feed(monitor, [20.0, None, None, None, None, None])
    assert [r.health for r in readings] == [
        Health.OK,
        Health.OK,
        Health.OK,
        Health.HELD,
        Health.HELD,
        Health.FAULTED,
    ]
    assert readings[3].reason.startswith("stale")


def test_stuck_value_is_detected():
    """A value that stays within stuck_tolerance for stuck_s is bad; noise beyond it is not."""
    checks = Checks(stuck_s=5.0, stuck_tolerance=0.001, hold_s=100.0)
    noisy = feed(SignalMonitor("T", checks), [20.0 + 0.01 * (k % 2) for k in range(20)])
    assert {r.health for r in noisy} == {Health.OK}
    stuck = feed(SignalMonitor("T", checks), [20.0] * 8)
    assert [r.health for r in stuck][4:7] == [Health.OK, Health.HELD, Health.HELD]


def test_recovery_after_fault_accepts_a_moved_value():
    """After a fault, the first in-range value is accepted even if it moved more than max_jump meanwhile."""
    monitor = SignalMonitor("T", Checks(max_jump=1.0, hold_s=1.0))
    readings = feed(monitor, [20.0, math.nan, math.nan, 27.0, 27.5])
    assert [r.health for r in readings] == [
        Health.OK,
        Health.HELD,
        Health.FAULTED,
        Health.OK,
        Health.OK,
    ]


def test_no_value_before_the_first_reading():
    """Before any good reading the signal is faulted with a NaN value (the model waits for it)."""
    reading = SignalMonitor("T", Checks()).update(0.0, None)
    assert reading.health is Health.FAULTED and math.isnan(reading.value)
