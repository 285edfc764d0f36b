"""Logs journald can filter: under systemd (stderr is the stream ``JOURNAL_STREAM`` names) every line of
``compd run`` starts with its syslog priority, ``<3>`` for a fault, the last error line too; on any other
stderr no line does. Events that go to MQTT are in the local log too."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import structlog.testing

from compd.cli.journal import PRIORITY
from compd.faultlog import Event
from compd.service.fleet.claim import Instance
from compd.service.fleet.mqttlink import Topics
from compd.service.fleet.payloads import Payloads
from tests.cli.closedport import RUN, WAIT_S, closed_port_config

#: The priority a JSON line's ``level`` must carry (sd-daemon(3): 3 err, 4 warning, 6 info, 7 debug).
BY_LEVEL = {"critical": 2, "error": 3, "warning": 4, "info": 6, "debug": 7}


def run_logging_to(stderr: Path, config: Path, journal_stream: str | None) -> list[str]:
    """``compd run`` for 1 s on a PLC that never answers, stderr to ``stderr``; its lines."""
    env = {k: v for k, v in os.environ.items() if k != "JOURNAL_STREAM"}
    with stderr.open("wb") as out:
        if journal_stream == "this file":
            stat = os.fstat(out.fileno())
            journal_stream = f"{stat.st_dev}:{stat.st_ino}"
        if journal_stream is not None:
            env["JOURNAL_STREAM"] = journal_stream
        subprocess.run(
            [
                *RUN,
                str(config),
                "--duration-s",
                "1",
                "--log-format",
                "json",
                "--log-level",
                "debug",
            ],
            stdout=subprocess.DEVNULL,
            stderr=out,
            env=env,
            timeout=WAIT_S,
        )
    return stderr.read_text().splitlines()


def test_under_systemd_each_line_carries_its_priority(tmp_path: Path) -> None:
    """Each JSON line ``<N>{...}`` with N its level's priority; the driver's fault and the exit error ``<3>``."""
    lines = run_logging_to(tmp_path / "stderr", closed_port_config(tmp_path), "this file")
    assert lines and all(line.startswith("<") for line in lines), lines
    priorities = {}
    for line in lines[:-1]:
        priority, _, text = line[1:].partition(">")
        entry = json.loads(text)
        assert int(priority) == BY_LEVEL[entry["level"]], line
        priorities[entry["event"]] = int(priority)
    assert priorities["driver open failed"] == 3
    assert priorities["stopped"] == 6
    assert lines[-1].startswith("<3>compd: error: driver plc not connected"), lines[-1]
    assert set(PRIORITY.values()) == set(BY_LEVEL.values())


def test_on_a_terminal_pipe_or_file_no_line_has_a_prefix(tmp_path: Path) -> None:
    """No JOURNAL_STREAM, or one naming another stream (stderr redirected since): plain JSON lines."""
    config = closed_port_config(tmp_path)
    for stream in (None, "1:2"):
        lines = run_logging_to(tmp_path / "stderr", config, stream)
        assert lines[0].startswith("{") and lines[-1].startswith("compd: error: "), lines
        assert not [line for line in lines if line.startswith("<")], lines


def test_model_outdated_is_logged_as_a_warning_not_only_published() -> None:
    """A birth that runs another model than the fleet's desired one: WARNING in the log, beside the event."""
    payloads = Payloads(
        Topics("compd", "mill-9"),
        Instance.this_process(),
        every_ticks=1,
        identity=lambda: {"model": {"sha256": "a" * 64}},
        wall=lambda: 0.0,
    )
    payloads.desired = {"sha256": "b" * 64, "name": "new"}
    events: list[Event] = []
    with structlog.testing.capture_logs() as logs:
        payloads.birth(events.append)
    assert [e.kind for e in events] == ["model_outdated"]
    (line,) = [line for line in logs if line["event"] == events[0].message]
    assert line["log_level"] == "warning" and line["desired"] == "b" * 64
