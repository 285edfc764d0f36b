"""A PLC that never answers is not normal operation: deploy/README.md's Modbus TCP config pointed at a
closed port says "not connected" on the live line, in ``compd status``, on the status page and in
``/healthz``, and a bounded ``compd run`` that never connected exits 3 with the fix in its message."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from compd.cli.args import EXIT_NOT_CONNECTED
from tests.cli.closedport import RUN, WAIT_S, closed_port_config
from tests.clirun import compd
from tests.mosquitto import free_port
from tests.report_screenshot import chromium, chromium_missing


def test_a_bounded_run_that_never_connected_says_so_and_exits_3(tmp_path: Path) -> None:
    """Every live line says the offset was NOT WRITTEN and plc is not connected; exit 3, naming compd read."""
    config = closed_port_config(tmp_path)
    done = subprocess.run(
        [*RUN, str(config), "--duration-s", "2", "--live-every", "1", "--log-format", "json"],
        capture_output=True,
        text=True,
        timeout=WAIT_S,
    )
    assert done.returncode == EXIT_NOT_CONNECTED, done.stdout + done.stderr
    lines = done.stdout.splitlines()
    assert len(lines) >= 2, done.stdout
    for line in lines:
        assert "Y offset NOT WRITTEN" in line and line.endswith("plc not connected"), line
        assert "offset written" not in line, line
    error = done.stderr.splitlines()[-1]
    assert error.startswith("compd: error: driver plc not connected in the 2 s run"), error
    assert "cannot connect" in error and f"compd read --config {config}" in error, error


def get(url: str) -> tuple[int, Any]:
    try:
        with urllib.request.urlopen(url, timeout=10) as answer:
            return answer.status, json.load(answer)
    except urllib.error.HTTPError as exc:
        return exc.code, json.load(exc)


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Path, str]]:
    """``compd run`` (no end) on the closed port, with its page; its config and URL once it has ticked."""
    folder = tmp_path_factory.mktemp("notconnected")
    port = free_port()
    config = closed_port_config(folder, http_port=port)
    log = folder / "compd.log"
    process = subprocess.Popen(
        [*RUN, str(config)],
        stdout=log.open("wb"),
        stderr=subprocess.STDOUT,
    )
    url = f"http://127.0.0.1:{port}/"
    deadline = time.monotonic() + WAIT_S
    try:
        while True:
            assert process.poll() is None, log.read_text()
            try:
                if get(url + "status.json")[1]["last_tick"] is not None:
                    break
            except OSError:
                pass
            assert time.monotonic() < deadline, log.read_text()
            time.sleep(0.1)
        yield config, url
    finally:
        os.kill(process.pid, signal.SIGTERM)
        process.wait(WAIT_S)


def test_status_status_json_and_healthz_say_not_connected(daemon: tuple[Path, str]) -> None:
    """``compd status`` in red words, ``/status.json``'s drivers, ``/healthz`` 503 with the driver's error."""
    config, url = daemon
    assert "driver plc not connected: nothing read or written through it" in compd(
        "status", "--config", config
    )
    status, snapshot = get(url + "status.json")
    assert (status, snapshot["drivers"]) == (200, {"plc": "not connected"})
    status, health = get(url + "healthz")
    assert status == 503 and not health["healthy"], health
    assert health["problems"][0].startswith("driver plc not connected (DriverDisconnectedError"), (
        health
    )


@pytest.mark.skipif(chromium_missing() is not None, reason=str(chromium_missing()))
def test_the_status_page_header_says_not_connected(daemon: tuple[Path, str]) -> None:
    """The page's badge: "faulted: plc not connected"; its drivers list: "not connected"."""
    _, url = daemon
    with chromium() as browser:
        page = browser.new_page()
        page.goto(url)
        page.locator("body[data-loaded]").wait_for(state="attached", timeout=WAIT_S * 1000)
        level = page.locator("#level")
        assert level.inner_text().endswith(": plc not connected"), level.inner_text()
        assert "not connected" in page.locator("#drivers").inner_text()


def test_the_live_view_on_a_terminal_says_not_connected_and_not_written(tmp_path: Path) -> None:
    """On a 120-column terminal: the header ends "plc not connected"; the axis row "not written"."""
    from tests.cli.terminal import run_in_terminal

    config = closed_port_config(tmp_path)
    screen = run_in_terminal(["run", "--config", str(config), "--duration-s", "2"])
    text = "\n".join(screen.lines)
    assert screen.returncode == EXIT_NOT_CONNECTED, text
    assert any(line.rstrip().endswith("plc not connected") for line in screen.lines), text
    (axis,) = [line for line in screen.lines if line.lstrip().startswith("Y ")]
    assert "not written (+0.00)" in axis, text


def test_a_recording_whose_controller_never_answered_exits_3_naming_the_fix(tmp_path: Path) -> None:
    """compd record on a PLC that never answers keeps its files but does not end as a calibration."""
    config = closed_port_config(tmp_path)
    out = tmp_path / "recording"
    done = subprocess.run(
        [*RUN[:-2], "record", "--config", str(config), "--duration-s", "2", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=WAIT_S,
    )
    assert done.returncode == EXIT_NOT_CONNECTED, done.stdout + done.stderr
    error = done.stderr.splitlines()[-1]
    assert error.startswith("compd: error: driver plc not connected in the "), error
    assert "s recording" in error and f"compd read --config {config}" in error, error
