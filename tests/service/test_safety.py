"""The offset safety stage: clamp, slew limit, NaN guard, fault freeze and ramp, status word."""

from __future__ import annotations

import math

from hypothesis import given, settings
from hypothesis import strategies as st

from compd.service.loop.safety import (
    SIGNAL_BIT0,
    AxisLimits,
    AxisSafety,
    FaultMode,
    Flag,
    Level,
    OutOfClamp,
    status_word,
)

LIMITS = AxisLimits(max_offset_um=20.0, max_rate_um_per_s=1.0)

targets = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(min_value=-100, max_value=100),
)


@settings(max_examples=200, deadline=None)
@given(
    steps=st.lists(st.tuples(targets, st.booleans()), min_size=1, max_size=200),
    period_s=st.sampled_from([0.1, 1.0, 2.0]),
    on_fault=st.sampled_from(list(FaultMode)),
)
def test_every_offset_is_finite_clamped_and_slew_limited(steps, period_s, on_fault):
    """For any targets (NaN, inf, huge) and faults, every offset is finite, within ±max, moving <= rate*T a tick."""
    stage = AxisSafety(LIMITS, period_s, on_fault=on_fault, fault_ramp_after_s=3.0)
    last = 0.0
    for k, (target, faulted) in enumerate(steps):
        out = stage.step(target, k * period_s, faulted=faulted).offset_um
        assert math.isfinite(out)
        assert abs(out) <= LIMITS.max_offset_um + 1e-12
        assert abs(out - last) <= LIMITS.max_rate_um_per_s * period_s + 1e-12
        last = out


def test_start_ramps_from_zero_at_the_slew_limit():
    """A large first target is approached from zero at the slew rate, then held at the clamp."""
    stage = AxisSafety(LIMITS, 1.0)
    offsets = [stage.step(50.0, float(k)).offset_um for k in range(25)]
    assert offsets[:3] == [1.0, 2.0, 3.0]
    assert offsets[-1] == LIMITS.max_offset_um


def test_small_targets_pass_unchanged():
    """Targets within the limits and the slew rate are written exactly."""
    stage = AxisSafety(LIMITS, 1.0)
    for k, target in enumerate([0.3, 0.9, 1.5, 1.2, 0.4]):
        result = stage.step(target, float(k))
        assert result.offset_um == target
        assert not (result.clamped or result.slewed or result.frozen)


def test_fault_freezes_then_ramps_to_zero():
    """A faulted input freezes the offset for fault_ramp_after_s, then it ramps to zero at the slew rate."""
    stage = AxisSafety(LIMITS, 1.0, on_fault=FaultMode.RAMP, fault_ramp_after_s=5.0, offset_um=4.0)
    offsets = [stage.step(10.0, float(k), faulted=True).offset_um for k in range(12)]
    assert offsets[:5] == [4.0] * 5
    assert offsets[5:10] == [3.0, 2.0, 1.0, 0.0, 0.0]


def test_freeze_mode_holds_until_recovery():
    """With on_fault=freeze the offset holds for the whole fault, and recovery slews back to the target."""
    stage = AxisSafety(
        LIMITS, 1.0, on_fault=FaultMode.FREEZE, fault_ramp_after_s=1.0, offset_um=4.0
    )
    held = [stage.step(-9.0, float(k), faulted=True).offset_um for k in range(100)]
    assert set(held) == {4.0}
    assert stage.step(6.0, 100.0).offset_um == 5.0


def test_nan_target_holds_the_last_offset():
    """A NaN or inf target keeps the last offset rather than writing it."""
    stage = AxisSafety(LIMITS, 1.0, offset_um=2.5)
    assert stage.step(math.nan, 0.0).offset_um == 2.5
    assert stage.step(math.inf, 1.0).frozen


@given(
    seed_um=st.floats(allow_nan=True, allow_infinity=True),
    policy=st.sampled_from(list(OutOfClamp)),
    targets_um=st.lists(targets, min_size=1, max_size=20),
)
def test_the_stage_never_starts_or_slews_outside_the_clamp(seed_um, policy, targets_um):
    """Whatever it is loaded with or recovers from (500, -3000, 3e38, NaN, inf um), its offset stays within ±max."""
    stage = AxisSafety(LIMITS, 1.0, offset_um=seed_um, on_out_of_clamp=policy)
    assert stage.within(stage.offset_um)
    stage.load(seed_um)
    assert stage.within(stage.offset_um)
    recovered = stage.recover(seed_um)
    assert recovered is None or stage.within(recovered)
    for k, target in enumerate(targets_um):
        assert stage.within(stage.step(target, float(k)).offset_um)


def test_a_value_beyond_the_clamp_is_replaced_by_the_policy_s_value():
    """500, -3000, 3e38 or NaN um held, 20 um clamp: hold keeps the last valid offset, edge the edge, refuse none."""
    for held_um, edge_um in ((500.0, 20.0), (-3000.0, -20.0), (3e38, 20.0), (math.nan, 4.0)):
        hold = AxisSafety(LIMITS, 1.0, offset_um=4.0)
        assert hold.recover(held_um) == 4.0 and hold.hold().offset_um == 4.0
        edge = AxisSafety(LIMITS, 1.0, offset_um=4.0, on_out_of_clamp=OutOfClamp.EDGE)
        assert edge.recover(held_um) == edge_um == edge.offset_um
        refuse = AxisSafety(LIMITS, 1.0, offset_um=4.0, on_out_of_clamp=OutOfClamp.REFUSE)
        assert refuse.recover(held_um) is None and refuse.offset_um == 4.0
    edge = AxisSafety(LIMITS, 1.0, on_out_of_clamp=OutOfClamp.EDGE)
    edge.recover(500.0)
    assert [edge.step(0.0, float(k)).offset_um for k in range(3)] == [19.0, 18.0, 17.0]


def test_an_offset_loaded_outside_the_clamp_is_clipped_not_walked_in():
    """An offset loaded beyond ±max (saved under a larger limit) starts at the clamp, not outside it."""
    stage = AxisSafety(LIMITS, 1.0, offset_um=23.0)
    assert stage.offset_um == 20.0
    assert [stage.step(0.0, float(k)).offset_um for k in range(3)] == [19.0, 18.0, 17.0]


def test_status_word_packs_level_flags_and_signal_bits():
    """Level in bits 0-1, flags in 2-7, one bit per signal from bit 8."""
    word = status_word(Level.DEGRADED, [Flag.SLEWING], [False, True])
    assert word == 1 | 8 | (1 << (SIGNAL_BIT0 + 1))


def test_the_mismatch_bit_follows_the_signal_bits():
    """The offset readback mismatch is the bit after the last signal's, and absent when 24 signals fill the word."""
    word = status_word(Level.DEGRADED, [], [False] * 6, mismatch=True)
    assert word == 1 | (1 << (SIGNAL_BIT0 + 6)) and word < 1 << 16  # fits a 16-bit register
    assert status_word(Level.OK, [], [False] * 23, mismatch=True) == 1 << 31
    assert status_word(Level.OK, [], [False] * 24, mismatch=True) == 0
