"""Acceptance 6: a fault-injection soak -- a fault every ~5 minutes of a shift, every kind -- ends clean.

compd's service runs against the simulated machine's Modbus PLC on virtual
time (:mod:`compd.sim.soak`) while PLC restarts that clear the offset
register, link drops, a garbage server on the port, corrupted state files
between restarts, bad model loads, hard kills and values outside the clamp
set by the PLC's program, malformed PLC replies, hundreds of slow clients
on the HTTP port and the control socket (while the status is asked for and
``/metrics`` scraped), reloads (SIGHUP's code path) and sensor faults on the
model's inputs (a plausible wrong value, a glitch, a stuck sensor, a wire
break) strike in a seeded order; every service is handed a retained and a
replayed roll-out command. A witness on the PLC's write path judges every
value the offset register receives; each sensor fault's cost is measured
against the same shift without faults. The 8-hour run is
``benchmarks/soak_faults.py``.
"""

from __future__ import annotations

import asyncio
import math
from pathlib import Path

import numpy as np

from compd.sim.soak import Soak, soak_config
from compd.sim.soakfaults import FAULT_KINDS, SENSOR_KINDS, Fault, draw_faults
from compd.sim.soaksensors import compensated_um, excess_lines

HOURS = 1.5
SEED = 13  # slow clients on HTTP (a scrape under them), malformed replies of two shapes


def test_a_faulted_shift_ends_with_no_crash_no_jump_and_no_unacknowledged_offset(
    short_dir: Path,
) -> None:
    """90 min, a fault every 3-7 min, every kind: 0 crashes, writes out of clamp, over-limit steps, unacknowledged."""
    faults = draw_faults(HOURS * 3600, SEED, every_s=(180.0, 420.0))
    config = soak_config(short_dir, hours=HOURS, seed=SEED)
    # No fault-free reference run here (the short soak below measures against one): half the time.
    result = asyncio.run(Soak(config, faults, reference=False).run())

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
    assert result.scrapes_answered >= 1 and result.scrapes_unanswered == 0, result.errors
    # A reload never stops the service; each sensor fault strikes a model input.
    assert result.reloads_done == result.faults["sighup"]
    assert len(result.sensor_faults) == sum(result.faults[k] for k in SENSOR_KINDS)


#: A short soak of the sensor faults, a reload with its config changed and broken, a state file
#: with ticks of 1e400 between two services, and slow HTTP clients during a scrape.
SHORT = [
    Fault(300.0, "sensor_offset", "+15", 100.0),
    Fault(450.0, "glitch", "60", 40.0),
    Fault(600.0, "stuck", "", 100.0),
    Fault(800.0, "wire_break", "high", 60.0),
    Fault(900.0, "sighup", "changed"),
    Fault(950.0, "sighup", "broken"),
    Fault(1000.0, "state_corrupt", "ticks_1e400"),
    Fault(1100.0, "wire_break", "nan", 60.0),
    Fault(1250.0, "slow_clients", "http", 30.0),
]
SHORT_SENSORS = [f for f in SHORT if f.kind in SENSOR_KINDS]


def test_sensor_faults_and_reloads_end_clean_and_each_sensor_faults_cost_is_measured(
    short_dir: Path,
) -> None:
    """30 min: each sensor fault on the next model input; the verdict prints its excess over the fault-free run."""
    soak = Soak(soak_config(short_dir, hours=0.5, seed=SEED), SHORT)
    result = asyncio.run(soak.run())

    assert result.passed and result.faults.total() == len(SHORT), result.errors
    inputs = ["T_spindle_degC", "T_headstock_degC", "T_column_front_degC", "T_ambient_degC"]
    assert len(SHORT_SENSORS) == 5
    assert [e.signal for e in result.sensor_faults] == [*inputs, inputs[0]]  # each in turn
    assert result.reloads_done == 2 and result.services == 2  # reloads stop nothing
    assert result.states_set_aside == 1 and result.scrapes_answered == 1
    assert result.sensor_faults[0].estimated_s >= 100.0  # the plausible wrong value stood in for
    # The reference is the same shift: the same until the first fault (a tick's slew of slack
    # for a read that timed out in one run under load).
    assert soak.sensors.reference_um is not None
    np.testing.assert_allclose(
        compensated_um(soak.machine, "Z")[:300], soak.sensors.reference_um[:300], atol=1.0
    )
    header, *lines = excess_lines(result.sensor_faults)
    rows, summary = lines[: len(SHORT_SENSORS)], lines[len(SHORT_SENSORS) :]
    assert "excess" in header and summary[0].startswith("excess over the fault-free run")
    for episode, row in zip(result.sensor_faults, rows, strict=True):
        assert math.isfinite(episode.excess_um)
        assert row.startswith(f"{episode.kind} {episode.variant}".strip()), row
        assert f"{episode.excess_um:+.2f}" in row and episode.signal in row
