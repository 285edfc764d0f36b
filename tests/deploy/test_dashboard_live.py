"""The fleet dashboard's Status panel as Grafana shows it: its queries run by a real Prometheus that
scrapes a real ``compd run``, each series reduced to its last value and put through the panel's
value mappings. A live healthy daemon reads "ok" in green, a killed one "down" in red.

Grafana itself is not installed here (no Debian package); what it adds to these numbers is only the
reduction and the mappings, which :func:`displayed` applies as the panel's JSON says.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
import urllib.parse
import urllib.request
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
import yaml

from tests.mosquitto import free_port, machine_config

DASHBOARD = Path(__file__).parents[2] / "deploy" / "grafana" / "compd-fleet.json"
PROMETHEUS = shutil.which("prometheus")
MACHINE_ID = "mill-dash-1"
#: Guards against a hang on a loaded machine, never timings the test relies on (s).
WAIT_S = 120.0
#: Prometheus scrapes this often here (s); a shop's is 15-60 s, which changes nothing the panel shows.
SCRAPE_S = 1
#: How far back the panel's range query looks, as a dashboard's time range does (s).
RANGE_S = 600

pytestmark = pytest.mark.skipif(
    PROMETHEUS is None,
    reason="prometheus is missing: .ci/install-system-packages installs Debian's prometheus",
)


def status_panel() -> dict[str, Any]:
    doc = json.loads(DASHBOARD.read_text())
    (panel,) = [p for p in doc["panels"] if p.get("title") == "Status"]
    return panel


def mapped(panel: dict[str, Any], value: float) -> tuple[str, str | None]:
    """The text and colour the panel's value mappings give ``value`` (Grafana's order: first match)."""
    for mapping in panel["fieldConfig"]["defaults"].get("mappings", []):
        if mapping["type"] == "value":
            for key, result in mapping["options"].items():
                if float(key) == value:
                    return result.get("text", key), result.get("color")
        elif mapping["type"] == "range":
            low, high = mapping["options"].get("from"), mapping["options"].get("to")
            if (low is None or value >= low) and (high is None or value <= high):
                return mapping["options"]["result"].get("text", str(value)), mapping["options"][
                    "result"
                ].get("color")
        else:  # a kind this helper does not know must not pass unseen
            raise AssertionError(f"mapping type {mapping['type']!r} not applied by this test")
    return f"{value:g}", None


def displayed(panel: dict[str, Any], prometheus: str) -> list[tuple[str, str | None]]:
    """Each value the stat panel shows: every target's range query, each series' last non-null value, mapped."""
    # Grafana's default for a stat panel that names none: the last non-null value of each series.
    reduce = panel.get("options", {}).get(
        "reduceOptions", {"calcs": ["lastNotNull"], "values": False}
    )
    assert reduce["calcs"] == ["lastNotNull"] and not reduce["values"], reduce
    shown = []
    end_s = time.time()
    for target in panel["targets"]:
        expr = target["expr"].replace("$machine_id", MACHINE_ID)
        query = {"query": expr, "start": end_s - RANGE_S, "end": end_s, "step": SCRAPE_S}
        for series in api(prometheus, "query_range", query):
            values = [float(v) for _, v in series["values"] if v not in ("NaN", None)]
            if values:
                shown.append(mapped(panel, values[-1]))
    return shown


def api(prometheus: str, path: str, query: dict[str, Any]) -> list[dict[str, Any]]:
    url = f"{prometheus}api/v1/{path}?{urllib.parse.urlencode(query)}"
    with urllib.request.urlopen(url, timeout=10) as answer:
        reply = json.load(answer)
    assert reply["status"] == "success", reply
    return list(reply["data"]["result"])


def wait_for(what: str, condition: Any, log: Path) -> Any:
    deadline = time.monotonic() + WAIT_S
    while True:
        try:
            if found := condition():
                return found
        except OSError:
            pass  # not listening yet
        assert time.monotonic() < deadline, f"never: {what}\n{log.read_text()[-4000:]}"
        time.sleep(0.2)


def shows(panel: dict[str, Any], prometheus: str, expected: list[tuple[str, str | None]]) -> None:
    """Wait until the panel shows ``expected``; else fail with what it showed last."""
    deadline = time.monotonic() + WAIT_S
    while (shown := displayed(panel, prometheus)) != expected:
        assert time.monotonic() < deadline, f"the panel shows {shown}, not {expected}"
        time.sleep(SCRAPE_S)


@contextmanager
def running(command: list[str], log: Path) -> Iterator[subprocess.Popen[bytes]]:
    process = subprocess.Popen(command, stdout=log.open("wb"), stderr=subprocess.STDOUT)
    try:
        yield process
    finally:
        if process.poll() is None:
            os.kill(process.pid, signal.SIGKILL)
            process.wait()


def test_status_panel_says_ok_for_a_live_daemon_and_down_in_red_for_a_killed_one(
    tmp_path: Path,
) -> None:
    """Alive and healthy: one value, "ok", green. Killed: one value, "down", red, never "ok" or "degraded"."""
    config = machine_config(tmp_path / "run", telemetry=None)
    doc = yaml.safe_load(config.path.read_text())
    compd_port, prometheus_port = free_port(), free_port()
    doc["machine_id"] = MACHINE_ID
    doc["http"] = {"listen": "127.0.0.1", "port": compd_port}
    config.path.write_text(yaml.safe_dump(doc, sort_keys=False))
    scrape = {
        "global": {"scrape_interval": f"{SCRAPE_S}s", "evaluation_interval": f"{SCRAPE_S}s"},
        "scrape_configs": [
            {
                "job_name": "compd",
                "scrape_timeout": f"{SCRAPE_S}s",
                "static_configs": [{"targets": [f"127.0.0.1:{compd_port}"]}],
            }
        ],
    }
    (tmp_path / "prometheus.yml").write_text(yaml.safe_dump(scrape))
    prometheus = f"http://127.0.0.1:{prometheus_port}/"
    panel = status_panel()
    compd_log, prometheus_log = tmp_path / "compd.log", tmp_path / "prometheus.log"
    compd_run = [sys.executable, "-m", "compd.cli", "run", "--config", str(config.path)]
    with (
        running([*compd_run, "--time-scale", "10"], compd_log) as daemon,
        running(
            [
                str(PROMETHEUS),
                f"--config.file={tmp_path / 'prometheus.yml'}",
                f"--storage.tsdb.path={tmp_path / 'tsdb'}",
                f"--web.listen-address=127.0.0.1:{prometheus_port}",
            ],
            prometheus_log,
        ),
    ):
        level = f'compd_status_level * on(instance) group_left(machine_id) compd_info{{machine_id="{MACHINE_ID}"}}'
        wait_for(
            "Prometheus scrapes compd's status level",
            lambda: api(prometheus, "query", {"query": level}),
            prometheus_log,
        )
        wait_for(
            "the simulated machine runs healthy (level 0)",
            lambda: [s for s in api(prometheus, "query", {"query": level}) if s["value"][1] == "0"],
            compd_log,
        )
        # A scrape that times out on a loaded machine is a real "down" for a second: wait it out.
        shows(panel, prometheus, [("ok", "green")])

        os.kill(daemon.pid, signal.SIGKILL)
        daemon.wait()
        wait_for(
            "Prometheus sees the daemon down",
            lambda: api(prometheus, "query", {"query": 'up{job="compd"} == 0'}),
            prometheus_log,
        )
        shows(panel, prometheus, [("down", "red")])
