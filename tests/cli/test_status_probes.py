"""``compd status`` on a probed axis: the shift's probe RMS docs/commands.md promises, in the human output too."""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from compd.cli import main
from compd.service.control.socket import ControlServer
from tests.service.daemon_setup import short_socket, write_config


def _reply(shift_rms_um: float | None, shift_probes: int) -> dict[str, Any]:
    """A daemon's status answer with one probed axis, Z, in the shape ``--json`` prints."""
    z = {
        "output": "disp_z_um",
        "due": False,
        "disagrees": False,
        "adjustment_um": 1.25,
        "last_taken_age_s": 1800.0,
        "last": {"result": "accepted", "innovation_um": -0.412},
        "probes": shift_probes,
        "shift_rms_um": shift_rms_um,
        "shift_probes": shift_probes,
        "results": {"accepted": shift_probes},
    }
    return {
        "model": None,
        "counters": {"ticks": 10},
        "status_word": 0,
        "heartbeat": 1,
        "drivers": {"plc": "connected"},
        "offsets_um": {},
        "targets_um": {},
        "inputs": {},
        "probes": {"off": None, "fault": None, "axes": {"Z": z}},
    }


@pytest.fixture
def serve(tmp_path: Path) -> Iterator[tuple[Path, list[dict[str, Any]]]]:
    """A control socket answering ``status`` with the reply the test puts in the list; the config naming it."""
    config = write_config(tmp_path, {"control_socket": str(short_socket())})
    replies: list[dict[str, Any]] = []

    async def status(message: dict[str, Any]) -> dict[str, Any]:
        return replies[-1]

    async def live(started: threading.Event, stop: asyncio.Event) -> None:
        async with ControlServer(config.control_socket, {"status": status}):
            started.set()
            await stop.wait()

    loop = asyncio.new_event_loop()
    started, stop = threading.Event(), asyncio.Event()
    thread = threading.Thread(target=loop.run_until_complete, args=(live(started, stop),))
    thread.start()
    try:
        assert started.wait(60)
        yield config.path, replies
    finally:
        loop.call_soon_threadsafe(stop.set)
        thread.join(60)
        loop.close()


def test_status_prints_the_shift_s_probe_rms_per_probed_axis(serve, capsys) -> None:
    """Per probed axis, the line names the RMS of the shift's probe innovations and how many probes."""
    path, replies = serve
    replies.append(_reply(0.5234, 3))
    assert main(["status", "--config", str(path)]) == 0
    line = next(s for s in capsys.readouterr().out.splitlines() if "probes Z:" in s)
    assert "probe RMS this shift 0.523 um (3 probes)" in line, line


def test_status_says_so_when_the_shift_has_no_probe(serve, capsys) -> None:
    """Without a probe in the shift, the line says so rather than leaving the figure out."""
    path, replies = serve
    replies.append(_reply(None, 0))
    assert main(["status", "--config", str(path)]) == 0
    line = next(s for s in capsys.readouterr().out.splitlines() if "probes Z:" in s)
    assert "probe RMS this shift: no probe yet" in line, line
