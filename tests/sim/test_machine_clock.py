"""The simulated machine's clock tells how fast it runs, as the clock it wraps does."""

from __future__ import annotations

from typing import Any, cast

from compd.service.loop.clock import RealClock, VirtualClock
from compd.sim.plc.machine import MachineClock, SimulatedMachine

NO_MACHINE = cast(SimulatedMachine, cast(Any, None))  # the scale never touches the machine


def test_time_scale_is_the_wrapped_clocks() -> None:
    """x600 under --time-scale 600; None on virtual time, for status to label the machine's times."""
    assert MachineClock(RealClock(600.0), NO_MACHINE).time_scale == 600.0
    assert MachineClock(VirtualClock(), NO_MACHINE).time_scale is None
