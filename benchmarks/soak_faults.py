"""Fault-injection soak: an 8-hour shift on the simulated machine, a fault every few minutes; counts vs 0.

compd's real service runs against the simulated machine's Modbus TCP PLC on
127.0.0.1, on virtual time (:mod:`compd.sim.soak`). Every 2 to 6 virtual
minutes (seeded) one fault strikes, drawn from: a PLC restart that clears
its offset register; a link drop of 5-60 s; a garbage server on the PLC's
port for 5-30 s; the state file corrupted between a stop and a restart; a
bad model file sent to ``load`` over the control socket; a hard kill of the
service (no final save, no STOPPED word) and a restart on the same state
directory; a value outside the clamp put into the offset register by the
PLC's own program (500 um, -3000 um, the int32 extremes); for 5-30 s half
the PLC's replies malformed (well-framed Modbus of the wrong shape); for
10-60 s hundreds of slow clients holding half-sent requests on the status
page's HTTP port, the control socket or both, while the status is asked for
over both and ``/metrics`` scraped; a reload (SIGHUP's code path) with the
config file unchanged, changed or broken; and a model input's sensor, each
in turn, reading +15 or -25 degC off the truth (60-115 s), 60 degC for 40 s,
stuck (60-115 s) or broken (327.67, -200 or NaN for 30-115 s). The state
file's corruptions include ``"ticks": Infinity``, ``1e400``, ``-Infinity``,
an integer of 5,000 digits and ``"saved_at_unix_s": NaN``. The first
fourteen faults are one of each kind. Every service is also handed a fleet
roll-out command as a broker would: retained (at every start) and replayed.

A witness on the PLC's write path judges every value the offset register
receives against what it held just before. Printed beside the targets:

- crashes: an exception out of the service, or a service that cannot be built;
- offsets written outside the clamp (``max_offset_um`` = 150 um);
- steps above the slew limit (``max_rate_um_per_s * period_s`` = 1.0 um) from a
  value within the clamp (replacing one outside it is a correction, counted apart);
- offsets the service acknowledged (what its recorder writes) that the PLC never received;
- bad models the daemon accepted;
- retained or replayed roll-out commands the daemon took;
- driver exceptions outside the DriverError contract (malformed replies);
- status requests left unanswered under slow clients (``busy`` is an answer);
- ticks whose heartbeat the PLC missed under slow clients;
- ``/metrics`` scrapes that failed under slow clients;
- reloads not taken (a service stopped by one is counted a crash).

Then, per sensor fault, how long the service stood in for the sensor, and
the compensated error's excess over the same shift run first without faults
(:mod:`compd.sim.soaksensors`): the largest |error| during the fault and the
10 minutes after it, less the fault-free run's over the same window (um; a
figure, not a target).

Then, on the real clock 60 times faster, 20 minutes of the shift with
compd as ``compd run`` child processes, ``--real-kills`` of them (default 4)
killed with SIGKILL at random times and started again, behind the same
witness: crashes (a daemon that exits by itself, or not with 0 on the last
SIGTERM) and steps above the slew limit.

Targets (issues 14, 22 and 33): 0, 0, 0, 0, 0, 0, 0, 0, 0, 0 and 0; 0 and 0. Exit 1 if one is missed.
Run: ``PYTHONPATH=. python benchmarks/soak_faults.py [--hours H] [--seed N] [--real-kills K]``.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

import structlog
import yaml
from common import environment, verdict

from compd.errors import CompdError
from compd.service.control.socket import request
from compd.service.loop.clock import RealClock
from compd.service.loop.ticks import run_periodic
from compd.sim.plc.run import start_machine
from compd.sim.soak import Soak, soak_config
from compd.sim.soakfaults import FAULT_KINDS, draw_faults
from compd.sim.soaksensors import excess_lines
from compd.sim.soakwitness import SoakResult


def quiet() -> None:
    """The soak provokes an ERROR per fault episode by design: keep the figures readable."""
    structlog.configure(wrapper_class=structlog.make_filtering_bound_logger(logging.CRITICAL))
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
    # pymodbus' client raises out of data_received on a frame it cannot decode: asyncio logs it.
    logging.getLogger("asyncio").setLevel(logging.CRITICAL)


def daemon(config: Path, log: Path, time_scale: float) -> subprocess.Popen[bytes]:
    """``compd run`` as a child process, on the real clock ``time_scale`` times faster."""
    command = [sys.executable, "-m", "compd.cli", "run", "--config", str(config)]
    command += ["--time-scale", str(time_scale)]
    return subprocess.Popen(command, stdout=log.open("ab"), stderr=subprocess.STDOUT)


async def real_kills(
    directory: Path, kills: int, seed: int, minutes: float, time_scale: float
) -> tuple[SoakResult, int, int]:
    """``compd run`` processes killed with SIGKILL at random times of a shift, each started again.

    The machine runs here on the real clock, ``time_scale`` times faster, its
    PLC behind the same witness as the soak's; compd runs as child processes.
    Returns the witness's result (slew violations; a daemon that exits by
    itself, or not with 0 on the last SIGTERM, is a crash), the kills made
    and the daemons started.
    """
    config = soak_config(directory, hours=minutes / 60, seed=seed)
    soak = Soak(config, [], seed=seed)  # its machine, PLC and witness, no in-process service
    doc = yaml.safe_load(config.path.read_text())
    del doc["simulation"]
    daemon_config = directory / "daemon.yaml"
    daemon_config.write_text(yaml.safe_dump(doc, sort_keys=False))
    log = directory / "daemons.log"
    rng = random.Random(seed)
    kill_at = sorted(rng.uniform(60.0, minutes * 60 - 60.0) for _ in range(kills))
    machine, result = soak.machine, soak.result
    await start_machine(config, machine)
    process = daemon(daemon_config, log, time_scale)
    started, killed = 1, 0

    async def step(t_s: float) -> None:
        nonlocal process, started, killed
        await machine.advance_to(t_s)
        if process.poll() is not None:  # it died by itself
            result.crashes += 1
            result.errors.append(f"t={t_s:g} s: compd run exited with {process.returncode}")
            process, started = daemon(daemon_config, log, time_scale), started + 1
        if kill_at and t_s >= kill_at[0]:
            kill_at.pop(0)
            process.send_signal(signal.SIGKILL)
            process.wait()
            killed += 1
            process, started = daemon(daemon_config, log, time_scale), started + 1

    try:
        await run_periodic(
            RealClock(time_scale), machine.sample_time_s, step,
            stop=asyncio.Event(), duration_s=machine.duration_s,
        )  # fmt: skip
    finally:
        await answering(config.control_socket, process)
        process.send_signal(signal.SIGTERM)
        if await asyncio.to_thread(process.wait, 30) != 0:
            result.crashes += 1
            result.errors.append(f"the last compd run exited with {process.returncode}")
        await machine.stop()
    return result, killed, started


async def answering(control: Path, process: subprocess.Popen[bytes]) -> None:
    """Wait (at most a minute) until ``process`` answers on its control socket, or has ended.

    A daemon answers once its SIGTERM handler is in place: one started just
    before the end is not sent SIGTERM while it is still importing (the signal's
    default action would end it, as systemd's stop does, with no saved state).
    """
    for _ in range(600):
        if process.poll() is not None:
            return
        with contextlib.suppress(CompdError):
            await request(control, {"cmd": "status"}, timeout_s=1.0)
            return
        await asyncio.sleep(0.1)


def print_counts(rows: tuple[tuple[str, int], ...]) -> None:
    """One line per count, beside its target of 0."""
    for name, count in rows:
        print(f"{name:<42}{count:>6}   target 0  {verdict(count == 0)}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hours", type=float, default=8.0, help="shift length (default 8)")
    parser.add_argument("--seed", type=int, default=1, help="seed of the faults and the shift")
    parser.add_argument(
        "--every-min", type=float, nargs=2, default=(2.0, 6.0), metavar=("MIN", "MAX"),
        help="minutes between faults, uniform (default 2 6)",
    )  # fmt: skip
    parser.add_argument(
        "--real-kills", type=int, default=4,
        help="SIGKILLs of a `compd run` process in a second, real-time run (default 4; 0: none)",
    )  # fmt: skip
    args = parser.parse_args()
    quiet()
    every_s = (args.every_min[0] * 60, args.every_min[1] * 60)
    faults = draw_faults(args.hours * 3600, args.seed, every_s=every_s)
    print(
        f"soak_faults: {args.hours:g} h production shift on virtual time, seed {args.seed}, "
        f"{len(faults)} faults every {args.every_min[0]:g}-{args.every_min[1]:g} min; "
        f"{environment()}, load average {os.getloadavg()[0]:.1f}"
    )
    directory = Path(tempfile.mkdtemp(prefix="compd-soak-", dir="/tmp"))  # a short socket path
    try:
        config = soak_config(directory, hours=args.hours, seed=args.seed)
        result = asyncio.run(Soak(config, faults, seed=args.seed).run())
    finally:
        shutil.rmtree(directory, ignore_errors=True)

    variants = {kind: Counter(f.variant for f in faults if f.kind == kind) for kind in FAULT_KINDS}
    print(f"{'fault':<15}{'injected':>9}   variants drawn")
    for kind in FAULT_KINDS:
        drawn = ", ".join(f"{v} {n}" for v, n in sorted(variants[kind].items()) if v)
        print(f"{kind:<15}{result.faults[kind]:>9}   {drawn}")
    print(f"{'total':<15}{result.faults.total():>9}")
    print()
    rows = (
        ("crashes", result.crashes),
        ("offsets written outside the clamp", result.outside_clamp),
        ("steps above the slew limit", result.slew_violations),
        ("offsets acknowledged, never received", result.unacknowledged),
        ("bad models accepted", result.bad_models_accepted),
        ("retained/replayed roll-outs taken", result.rollouts_taken_again),
        ("driver exceptions outside the contract", result.driver_bugs),
        ("status requests unanswered (slow clients)", result.status_unanswered),
        ("heartbeats missed (slow clients)", result.heartbeats_missed),
        ("/metrics scrapes failed (slow clients)", result.scrapes_unanswered),
        ("reloads not taken", result.faults["sighup"] - result.reloads_done),
    )
    print_counts(rows)
    print()
    print(
        f"simulated {result.simulated_s / 3600:g} h in {result.wall_s:.0f} s wall; "
        f"{result.ticks} ticks by {result.services} services; "
        f"{result.offsets_received} offsets received by the PLC, largest step "
        f"{result.largest_step_um:g} um (limit 1 um); readback mismatches followed "
        f"{result.offset_mismatches}; offsets read back outside the clamp "
        f"{result.offsets_out_of_clamp}, replaced by {result.corrections} writes within it; "
        f"writes the PLC applied but compd never heard back "
        f"(killed mid-write, or a malformed reply) {result.landed_unacknowledged}; bad models refused "
        f"{result.bad_models_refused}; the roll-out taken {result.rollouts_taken}, its "
        f"retained copies and replays refused {result.rollouts_refused}; driver fault "
        f"episodes under malformed replies {result.malformed_faults}; slow clients opened "
        f"{result.slow_clients}, status requests answered {result.status_answered}, "
        f"turned away busy {result.status_busy}, longest real gap between two ticks under "
        f"them {result.largest_tick_gap_s * 1000:.0f} ms, /metrics scrapes answered "
        f"{result.scrapes_answered}; reloads taken {result.reloads_done}; state files set "
        f"aside {result.states_set_aside}; the fault-free reference run "
        f"{result.reference_wall_s:.0f} s wall"
    )
    print()
    for line in excess_lines(result.sensor_faults):
        print(line)
    for error in result.errors[:20]:
        print("  ", error)
    passed = result.passed
    if args.real_kills:
        passed &= real_kill_figures(args.real_kills, args.seed)
    print(f"soak: {verdict(passed)}")
    return 0 if passed else 1


def real_kill_figures(kills: int, seed: int) -> bool:
    minutes, time_scale = 20.0, 60.0
    directory = Path(tempfile.mkdtemp(prefix="compd-kill-", dir="/tmp"))
    try:
        started = time.perf_counter()
        result, killed, daemons = asyncio.run(
            real_kills(directory, kills, seed, minutes, time_scale)
        )
        wall_s = time.perf_counter() - started
    finally:
        shutil.rmtree(directory, ignore_errors=True)
    print()
    print(
        f"real SIGKILL: {minutes:g} min of the shift at {time_scale:g}x real time, `compd run` "
        f"killed {killed} times and started again ({daemons} processes), {wall_s:.0f} s wall"
    )
    print_counts(
        (
            ("crashes", result.crashes),
            ("offsets written outside the clamp", result.outside_clamp),
            ("steps above the slew limit", result.slew_violations),
        )
    )
    print(
        f"{result.offsets_received} offsets received by the PLC, largest step "
        f"{result.largest_step_um:g} um (limit 1 um)"
    )
    for error in result.errors[:20]:
        print("  ", error)
    return result.passed and killed == kills


if __name__ == "__main__":
    sys.exit(main())
