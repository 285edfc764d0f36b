"""What compd knows each offset point holds: seeds, mismatches, unknown values never written from."""

from __future__ import annotations

import math

import numpy as np
from structlog.testing import capture_logs

from compd.service.loop.offsets import AxisPoint, HeldOffsets
from compd.service.loop.safety import AxisLimits, AxisSafety, OutOfClamp

LIMITS = AxisLimits(max_offset_um=50.0, max_rate_um_per_s=1.0)


def held(axis: AxisPoint, offset_um: float = 0.0) -> HeldOffsets:
    return HeldOffsets([axis], {axis.name: AxisSafety(LIMITS, 1.0, offset_um=offset_um)})


def test_without_readback_the_seed_is_what_the_device_holds():
    """An axis without readback starts from its stage's seed (a resumed state) and follows acknowledged writes."""
    offsets = held(AxisPoint("Z", "disp_z_um", "plc", "z"), offset_um=4.0)
    assert offsets.known_um() == {"Z": 4.0}
    assert offsets.read_back({}) == 0 and not offsets.unknown
    assert offsets.written({"Z": 5.0}, {"plc": True}) == {"Z": 5.0}
    assert offsets.known_um() == {"Z": 5.0}


def test_an_offset_that_cannot_be_read_back_is_not_written():
    """A readback axis is unknown until read: it is left out of the writes, then seeded from what it reads."""
    axis = AxisPoint("Z", "disp_z_um", "plc", "z", readback=True)
    offsets = held(axis)
    assert offsets.read_back({}) == 0 and offsets.unknown == {"Z"}
    assert offsets.to_write({"Z": 1.0}) == {}
    assert offsets.read_back({"Z": 9.3}) == 0  # a seed, not a mismatch
    assert offsets.safety["Z"].offset_um == 9.3 and not offsets.unknown
    assert offsets.to_write({"Z": 8.3}) == {"Z": 8.3}


def test_a_failed_write_that_landed_is_not_a_mismatch():
    """A write that timed out but reached the PLC reads back as sent: re-seeded from it, not counted."""
    axis = AxisPoint("Z", "disp_z_um", "plc", "z", readback=True)
    offsets = held(axis)
    offsets.read_back({"Z": 2.0})
    assert offsets.written({"Z": 3.0}, {"plc": False}) == {}
    assert (
        offsets.safety["Z"].offset_um == 2.0
    )  # until known, the stage holds the acknowledged value
    assert offsets.read_back({"Z": 3.0}) == 0
    assert offsets.safety["Z"].offset_um == 3.0
    assert offsets.read_back({"Z": 0.0}) == 1  # now cleared behind compd's back


def test_integer_counts_never_add_up_to_more_than_a_slew_step():
    """In 0.3 um counts at a 1 um step, a write moves the register at most 3 counts, whatever the rounding."""
    axis = AxisPoint("Z", "disp_z_um", "plc", "z", scale=1 / 0.3, integer=True, readback=True)
    offsets = held(axis)
    offsets.read_back({"Z": 0.0})
    assert offsets.to_write({"Z": 1.0}) == {"Z": 3.0}  # round(3.33) = 3
    offsets.read_back({"Z": 1.0})  # the PLC holds 0.3 um; the stage, re-seeded, steps to 1.3
    assert offsets.to_write({"Z": 1.3}) == {"Z": 4.0}
    assert axis.toward(axis.encode(1.5), 1.0, 1.0) == 4.0  # round(5.0) = 5 is 4 counts away: 4


def clamped(policy: OutOfClamp, offset_um: float = 3.0) -> HeldOffsets:
    """Z in int32 counts of 0.1 um, read back, a 50 um clamp, seeded at ``offset_um``."""
    axis = AxisPoint("Z", "disp_z_um", "plc", "z", scale=10.0, integer=True, readback=True)
    stage = AxisSafety(LIMITS, 1.0, offset_um=offset_um, on_out_of_clamp=policy)
    return HeldOffsets([axis], {"Z": stage})


def test_a_value_read_back_outside_the_clamp_is_replaced_not_followed():
    """500 um, -3000 um, 1e30, 3e38, NaN or inf held at start: hold writes the seed exactly, never a step from it."""
    for raw in (5000.0, -30000.0, 1e31, 3e38, math.nan, -math.inf):
        offsets = clamped(OutOfClamp.HOLD)
        assert offsets.read_back({"Z": raw}) == 0
        assert offsets.out_of_clamp == {"Z": 3.0}
        assert offsets.safety["Z"].offset_um == 3.0  # not seeded from what the PLC holds
        assert offsets.to_write({"Z": offsets.safety["Z"].hold().offset_um}) == {"Z": 30.0}
        assert offsets.known_um() == {}  # nothing valid known: nothing saved as held


def test_edge_and_refuse_write_the_clamp_edge_or_nothing():
    """With edge the register gets the clamp edge nearest the held value; with refuse, nothing."""
    edge = clamped(OutOfClamp.EDGE)
    edge.read_back({"Z": -30000.0})
    assert edge.to_write({"Z": edge.safety["Z"].hold().offset_um}) == {"Z": -500.0}
    refuse = clamped(OutOfClamp.REFUSE)
    refuse.read_back({"Z": 5000.0})
    assert refuse.out_of_clamp == {"Z": None}
    assert refuse.to_write({"Z": 3.0}) == {}
    refuse.read_back({"Z": 120.0})  # the PLC holds 12 um again: followed from there
    assert refuse.out_of_clamp == {} and refuse.safety["Z"].offset_um == 12.0


def test_an_out_of_clamp_episode_is_logged_once():
    """A register stuck at 500 um for three ticks: one ERROR, then INFO when it holds a value within the clamp."""
    offsets = clamped(OutOfClamp.HOLD)
    with capture_logs() as logs:
        for raw in (5000.0, 5000.0, 5000.0, 30.0):
            offsets.read_back({"Z": raw})
    levels = [(e["log_level"], e["event"].split(":")[0]) for e in logs]
    assert levels == [
        ("error", "offset read back outside the clamp or not finite"),
        ("debug", "offset read back outside the clamp or not finite"),
        ("debug", "offset read back outside the clamp or not finite"),
        ("info", "offset read back within the clamp again"),
    ]


def test_a_count_rounded_at_the_clamp_is_within_it():
    """In 0.3 um counts a 50 um clamp is written as 167 counts (50.1 um): read back, that is no fault."""
    axis = AxisPoint("Z", "disp_z_um", "plc", "z", scale=1 / 0.3, integer=True, readback=True)
    offsets = held(axis)
    assert offsets.read_back({"Z": axis.encode(50.0)}) == 0 and offsets.out_of_clamp == {}
    assert offsets.read_back({"Z": axis.encode(50.0) + 1}) == 0 and offsets.out_of_clamp
    floats = AxisPoint("Z", "disp_z_um", "plc", "z", readback=True)
    assert float(np.float32(0.3)) > 0.3 and floats.within(float(np.float32(0.3)), 0.3)
    assert not floats.within(0.31, 0.3)
