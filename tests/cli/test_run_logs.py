"""`compd run`'s logs: on stderr, never in stdout's tables; the protocol libraries' debug never in them."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

from .test_live_terminal import short_dir, simulated_config

__all__ = ["short_dir"]  # the fixture, shared


def test_debug_logs_go_to_stderr_without_pymodbus_frames(short_dir: Path) -> None:
    """--log-level debug through a link drop: stdout has the summary only, stderr JSON lines, no pymodbus frames."""
    config = simulated_config(
        short_dir, faults=[{"kind": "drop", "driver": "plc", "at_s": 60, "duration_s": 20}]
    )
    done = subprocess.run(
        [sys.executable, "-m", "compd.cli", "run", "--config", str(config), "--time-scale", "max",
         "--duration-s", "180", "--log-level", "debug", "--log-format", "json"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert "thermal error at the tool centre point" in done.stdout
    assert '"level"' not in done.stdout and "[debug" not in done.stdout
    events = [json.loads(line) for line in done.stderr.splitlines()]
    assert any(e["level"] == "debug" for e in events), "compd's own debug is shown"
    assert any(e["event"] == "driver read failed" for e in events)
    # pymodbus's warnings come through as one DEBUG line each; its frames (send/recv: 0x..) never.
    # (A frame is hex bytes, "0x01 0x03 ..."; a random temp-dir name may hold "0x" too.)
    frame = re.compile(r"(send|recv):|0x[0-9a-f]{2} 0x[0-9a-f]{2}")
    frames = [e for e in events if frame.search(json.dumps(e))]
    assert frames == []


def test_a_piped_run_prints_a_line_at_start_and_each_simulated_hour(short_dir: Path) -> None:
    """Piped, with no --live-every: a start line naming the machine, then one progress line per simulated hour."""
    config = simulated_config(short_dir)
    done = subprocess.run(
        [sys.executable, "-m", "compd.cli", "run", "--config", str(config), "--time-scale", "max",
         "--duration-s", "7300"],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert lines[0].startswith("simulated machine: production, 8 h, seed 1"), lines[0]
    assert [line.split("h")[0] for line in lines[1:3]] == ["t   1.00 ", "t   2.00 "], done.stdout
