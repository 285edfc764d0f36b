"""Acceptance 5: the daemon killed (SIGKILL) mid-shift and started again resumes without a jump.

The simulated machine runs on its own (``compd simulate-machine``'s code) in
a thread of the test; ``compd run`` runs as a child process against it and is
killed while the machine is warm. The PLC holds the last offset; the second
daemon resumes the saved model state and offsets, so the offset the PLC sees
never moves faster than the slew limit.
"""

from __future__ import annotations

import asyncio
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from compd.sim.plc.machine import SimulatedMachine
from compd.sim.plc.run import serve_machine
from tests.acceptance.conftest import machine_doc, write_config

TIME_SCALE = 100.0
KILL_AT_S = 900.0  # machine time


class MachineThread:
    """The simulated machine on a real clock ``TIME_SCALE`` times faster, in a thread."""

    def __init__(self, config: Any) -> None:
        self.machine: SimulatedMachine | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop: asyncio.Event | None = None
        self._thread = threading.Thread(target=asyncio.run, args=(self._main(config),))

    async def _main(self, config: Any) -> None:
        self._loop, self._stop = asyncio.get_running_loop(), asyncio.Event()

        def seen(machine: SimulatedMachine) -> None:
            self.machine = machine

        await serve_machine(config, time_scale=TIME_SCALE, stop=self._stop, on_step=seen)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        if self._loop is not None and self._stop is not None:
            self._loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(timeout=30)

    def wait_for(self, condition: Any, timeout_s: float = 60.0) -> SimulatedMachine:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.machine is not None and condition(self.machine):
                return self.machine
            time.sleep(0.02)
        raise AssertionError(f"timed out; machine at {self.machine and self.machine.now_s} s")


def daemon(config: Path, log: Path) -> subprocess.Popen[bytes]:
    command = [sys.executable, "-m", "compd.cli", "run", "--config", config]
    command += ["--time-scale", str(TIME_SCALE), "--log-format", "json"]
    return subprocess.Popen(command, stdout=log.open("wb"), stderr=subprocess.STDOUT)


def model_events(log: Path) -> list[dict[str, Any]]:
    lines = [json.loads(line) for line in log.read_text().splitlines() if line.startswith("{")]
    return [line for line in lines if line.get("event") == "model"]


def test_a_killed_daemon_resumes_its_state_and_the_offset_does_not_jump(
    calibrated_model: Path, short_dir: Path
) -> None:
    """SIGKILL at 15 min of a warm shift, start again: resumed, offset continuous within the slew limit."""
    doc = machine_doc(
        short_dir, calibrated_model, simulation={"scenario": "production", "hours": 2, "seed": 7}
    )
    doc["state"]["save_every_ticks"] = 10
    # The restart takes seconds of real time, x100 on the machine's clock; a busy CI machine
    # must not age the state past the limit (the limit has its own tests).
    doc["state"]["resume_max_age_s"] = 4 * 3600
    machine = MachineThread(write_config(short_dir, doc, "machine.yaml"))
    del doc["simulation"]
    daemon_config = short_dir / "daemon.yaml"
    daemon_config.write_text(yaml.safe_dump(doc, sort_keys=False))
    first = daemon(daemon_config, short_dir / "first.log")
    second = None
    try:
        time.sleep(1.0)  # the daemon connects as soon as the PLC is up
        machine.start()
        # Warm and compensated: on a loaded machine the daemon's ramp can trail the twin's clock,
        # so wait for the offset itself rather than for a time.
        warm = machine.wait_for(
            lambda m: (
                m.now_s >= KILL_AT_S
                and m.plc.heartbeat_changes > 100
                and abs(m.applied_um["z"]) > 5
            )
        )
        first.send_signal(signal.SIGKILL)
        first.wait(timeout=10)
        held_um = warm.applied_um["z"]
        killed_s = warm.now_s
        second = daemon(daemon_config, short_dir / "second.log")
        changes = warm.plc.heartbeat_changes
        machine.wait_for(lambda m: m.plc.heartbeat_changes > changes + 300)
        second.send_signal(signal.SIGTERM)
        assert second.wait(timeout=20) == 0
    finally:
        for process in (first, second):
            if process is not None and process.poll() is None:
                process.kill()
        machine.stop()

    assert abs(held_um) > 5, "the machine is warm and compensated when the daemon dies"
    (resumed,) = model_events(short_dir / "second.log")
    assert resumed["resume"] is True, resumed["reason"]
    end = warm.k + 1
    steps = np.abs(np.diff(warm.offset_um[:end, 2]))
    rate = doc["outputs"]["Z"]["max_rate_um_per_s"]
    assert steps.max() <= rate * warm.sample_time_s * 2 + 0.1, "no jump across the restart"
    after = warm.offset_um[int(killed_s / warm.sample_time_s) : end, 2]
    assert abs(after[-1] - held_um) < 60, "the second daemon went on compensating"
    assert os.path.exists(short_dir / "state" / "state.json")
