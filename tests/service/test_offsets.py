"""What compd knows each offset point holds: seeds, mismatches, unknown values never written from."""

from __future__ import annotations

from compd.service.offsets import AxisPoint, HeldOffsets
from compd.service.safety import AxisLimits, AxisSafety

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
