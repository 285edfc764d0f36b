"""The status page of a real ``compd run`` in headless chromium: it names its machine, turns dead when killed."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest
import yaml

from tests.mosquitto import free_port, machine_config
from tests.report_screenshot import chromium, chromium_missing

pytestmark = pytest.mark.skipif(chromium_missing() is not None, reason=str(chromium_missing()))

MACHINE_ID = "mill-dead-7"
#: Guards against a hang, not timings: generous for a busy CI machine (ms, s).
LOAD_TIMEOUT_MS = 60_000
DEAD_TIMEOUT_MS = 30_000
START_S = 120.0


def start_daemon(directory: Path, log: Path) -> tuple[subprocess.Popen[bytes], str]:
    """``compd run`` on the simulated machine, ten times real time, its page on 127.0.0.1; its URL once it answers."""
    config = machine_config(directory, telemetry=None)
    doc = yaml.safe_load(config.path.read_text())
    port = free_port()
    doc["machine_id"] = MACHINE_ID
    doc["http"] = {"listen": "127.0.0.1", "port": port}
    config.path.write_text(yaml.safe_dump(doc, sort_keys=False))
    command = [sys.executable, "-m", "compd.cli", "run", "--config", str(config.path)]
    daemon = subprocess.Popen(
        [*command, "--time-scale", "10"], stdout=log.open("wb"), stderr=subprocess.STDOUT
    )
    url = f"http://127.0.0.1:{port}/"
    deadline = time.monotonic() + START_S
    while True:
        assert daemon.poll() is None, log.read_text()
        try:
            with urllib.request.urlopen(url + "status.json", timeout=5) as answer:
                if b'"last_tick": null' not in answer.read():
                    return daemon, url
        except OSError:
            pass
        assert time.monotonic() < deadline, f"compd never answered on {url}: {log.read_text()}"
        time.sleep(0.1)


def test_a_killed_compd_turns_the_page_dead_and_the_tab_names_the_machine(tmp_path: Path) -> None:
    """Alive: machine_id in title and header, a level badge; after SIGKILL: header 'no answer for N s', never 'ok'."""
    daemon, url = start_daemon(tmp_path / "run", tmp_path / "compd.log")
    try:
        with chromium() as browser:
            page = browser.new_page(viewport={"width": 1280, "height": 800})
            page.goto(url)
            # Locators, not wait_for_function: its predicate is eval'd, which the page's policy forbids.
            page.locator("body[data-state='alive']").wait_for(
                state="attached", timeout=LOAD_TIMEOUT_MS
            )
            assert MACHINE_ID in page.title()
            assert page.locator("header #machine").inner_text() == MACHINE_ID
            assert page.locator("#level").inner_text() in {"ok", "degraded", "faulted"}

            os.kill(daemon.pid, signal.SIGKILL)
            daemon.wait()
            page.locator("body[data-state='dead']").wait_for(
                state="attached", timeout=DEAD_TIMEOUT_MS
            )
            level = page.locator("#level")
            assert level.inner_text().startswith("no answer for ")
            assert "dead" in (level.get_attribute("class") or "").split()
            assert "ok" not in (level.get_attribute("class") or "").split()
            assert page.title().startswith("\u2716 ") and MACHINE_ID in page.title()
            page.screenshot(path=str(tmp_path / "dead.png"))
    finally:
        if daemon.poll() is None:
            os.kill(daemon.pid, signal.SIGKILL)
            daemon.wait()
