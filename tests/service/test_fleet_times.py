"""Births and deaths carry the real time, so `compd fleet list` never shows a simulated clock's as one to trust."""

from __future__ import annotations

import time

from compd.cli.fleetlist import Machine, last_seen
from compd.service.fleet.claim import Instance
from compd.service.fleet.mqttlink import Topics
from compd.service.fleet.payloads import Payloads

HOUR_S = 3600.0


def _payloads(ahead_s: float) -> Payloads:
    """A daemon's payloads whose service clock runs ``ahead_s`` ahead of the real one (``--time-scale 60``)."""
    return Payloads(
        Topics("compd", "mill-1"),
        Instance.this_process(),
        every_ticks=1,
        identity=dict,
        wall=lambda: time.time() + ahead_s,
    )


def test_a_death_under_a_fast_clock_is_stamped_with_the_real_time_and_the_machines_apart() -> None:
    """``time`` is when it was sent (real clock); the service clock's own reading is ``machine_time``."""
    before = time.time()
    death = _payloads(HOUR_S).death("stopped")
    after = time.time()
    assert before <= death["time"] <= after
    assert before + HOUR_S <= death["machine_time"] <= after + HOUR_S


def test_on_the_real_clock_a_birth_has_no_machine_time() -> None:
    """A daemon on the real clock stamps one time: no ``machine_time`` beside it."""
    payloads = _payloads(0.0)
    assert "machine_time" not in payloads.header("birth")


def _stopped(at_unix_s: float) -> Machine:
    return Machine("mill-1", "offline", "stopped", "host", 1, "0", "twin-z", "0" * 64, None, None,
                   at_unix_s, at_unix_s - 60)  # fmt: skip


def test_fleet_list_marks_a_stop_stamped_in_the_future_as_a_simulated_clocks() -> None:
    """An hour ahead of the reader's clock (an older daemon's simulated stamp) is said to be so."""
    now = 1_790_000_000.0
    assert last_seen(_stopped(now - 60), now) == "2026-09-21 14:12:20Z"
    assert last_seen(_stopped(now + HOUR_S), now).endswith(
        "(a simulated clock's, ahead of this one)"
    )
