"""Acceptance 6: a fault-injection soak -- a fault every ~5 minutes of a shift, every kind -- ends clean.

compd's service runs against the simulated machine's Modbus PLC on virtual
time (:mod:`compd.sim.soak`) while PLC restarts that clear the offset
register, link drops, a garbage server on the port, corrupted state files
between restarts, bad model loads, hard kills and values outside the clamp
set by the PLC's program, malformed PLC replies, and hundreds of slow clients
on the HTTP port and the control socket strike in a seeded order; every
service is handed a retained and a replayed roll-out command.
A witness on the PLC's write path judges every value the offset register
receives. The 8-hour run is ``benchmarks/soak_faults.py``.
"""

from __future__ import annotations

import asyncio
from pathlib import Path

from compd.sim.soak import Soak, soak_config
from compd.sim.soakfaults import FAULT_KINDS, draw_faults

HOURS = 1.5
SEED = 13  # slow clients on both servers, malformed replies of two shapes


def test_a_faulted_shift_ends_with_no_crash_no_jump_and_no_unacknowledged_offset(
    short_dir: Path,
) -> None:
    """90 min, a fault every 3-7 min, every kind: 0 crashes, writes out of clamp, over-limit steps, unacknowledged."""
    faults = draw_faults(HOURS * 3600, SEED, every_s=(180.0, 420.0))
    result = asyncio.run(Soak(soak_config(short_dir, hours=HOURS, seed=SEED), faults).run())

    assert set(result.faults) == set(FAULT_KINDS) and result.faults.total() == len(faults)
    assert result.crashes == 0, result.errors
    assert result.slew_violations == 0, result.errors
    assert result.outside_clamp == 0, result.errors
    # Each value set outside the clamp is read back as such and replaced by one write.
    assert result.offsets_out_of_clamp == result.corrections == result.faults["out_of_clamp"]
    assert result.unacknowledged == 0, result.errors
    assert (
        result.bad_models_accepted == 0 and result.bad_models_refused == result.faults["bad_model"]
    )
    # The roll-out is taken once; its retained copy and its replay are refused by every service.
    assert result.rollouts_taken == 1 and result.rollouts_taken_again == 0, result.errors
    assert result.rollouts_refused == 2 * result.services
    # Every restart is a new service; the shift ran to its end with the PLC written throughout.
    restarts = result.faults["kill"] + result.faults["state_corrupt"]
    assert result.services == restarts + 1
    assert result.simulated_s == HOURS * 3600
    assert result.offsets_received > 0.8 * result.ticks
    # Cleared registers are seen as readback mismatches; no other fault is mistaken for one.
    assert 0 < result.offset_mismatches <= result.faults["plc_reset"]
    # Malformed replies are driver faults, each episode seen, none raised outside the contract.
    assert result.malformed_faults >= result.faults["malformed"] and result.driver_bugs == 0
    # Under slow clients the status is answered (over HTTP, and on the control socket once the
    # clients are gone; during them it may say busy) and the PLC gets every tick's heartbeat.
    assert result.slow_clients > 0 and result.status_unanswered == 0, result.errors
    assert result.status_answered >= 2 * result.faults["slow_clients"]
    assert result.heartbeats_missed == 0
