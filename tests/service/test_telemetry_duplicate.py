"""Two daemons with one ``machine_id`` on a real mosquitto: the second stands by, naming the first's host.

Each is its own ``compd run`` process; a paho subscriber keeps what the
broker delivers under the machine's topics.
"""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import paho.mqtt.client as mqtt
import pytest
from paho.mqtt.enums import CallbackAPIVersion

from tests.mosquitto import WAIT_S, Mosquitto, Subscriber, machine_config, mosquitto_binary

pytestmark = pytest.mark.skipif(
    mosquitto_binary() is None,
    reason="mosquitto is not installed: run .ci/install-system-packages",
)


def _start(folder: Path, port: int) -> tuple[subprocess.Popen[bytes], Path]:
    telemetry = {"machine_id": "mill-d", "host": "127.0.0.1", "port": port, "every_ticks": 1}
    config = machine_config(folder, telemetry=telemetry)
    log = folder / "compd.log"
    command = [sys.executable, "-m", "compd.cli", "run", "--config", str(config.path)]
    command += ["--time-scale", "10"]
    daemon = subprocess.Popen(command, stdout=log.open("wb"), stderr=subprocess.STDOUT)
    return daemon, log


def _wait_for_line(log: Path, text: str) -> str:
    """Wait (real time, bounded by WAIT_S) until ``log`` has a line with ``text``; that line."""
    deadline = time.monotonic() + WAIT_S
    while time.monotonic() < deadline:
        for line in log.read_text(errors="replace").splitlines():
            if text in line:
                return line
        time.sleep(0.05)
    raise AssertionError(f"{log} never said {text!r}:\n{log.read_text()[-3000:]}")


def test_a_second_daemon_with_the_same_machine_id_stands_by_and_takes_over_when_the_first_stops(
    broker: Mosquitto, tmp_path: Path
):
    """The second publishes nothing, logs the first's host and pid, and is born only after the first's death."""
    daemons = []
    try:
        with Subscriber(broker.port, "compd/mill-d/+") as sub:
            first, _ = _start(tmp_path / "first", broker.port)
            daemons.append(first)
            sub.wait_for(lambda s: s.of("birth"), "the first daemon's birth")
            second, second_log = _start(tmp_path / "second", broker.port)
            daemons.append(second)
            line = _wait_for_line(second_log, "telemetry stands by")
            assert f"{socket.gethostname()} (pid {first.pid})" in line
            statuses = len(sub.of("status"))
            sub.wait_for(lambda s: len(s.of("status")) >= statuses + 20, "the first going on")
            births, deaths = sub.of("birth"), sub.of("death")
            assert [b["instance"]["pid"] for b in births] == [first.pid], "one birth: the first's"
            assert not deaths, "no fight: nobody thrown off the broker"
            assert {s["session"] for s in sub.of("status")} == {births[0]["session"]}

            first.send_signal(signal.SIGTERM)
            assert first.wait(timeout=WAIT_S) == 0
            sub.wait_for(
                lambda s: any(b["instance"]["pid"] == second.pid for b in s.of("birth")),
                "the second daemon's birth after the first stopped",
            )
            _wait_for_line(second_log, "telemetry publishes: the other daemon is gone")
            deaths = sub.of("death")
            assert [(d["reason"], d["instance"]["pid"]) for d in deaths] == [("stopped", first.pid)]
    finally:
        for daemon in daemons:
            if daemon.poll() is None:
                daemon.kill()
                daemon.wait()


def test_of_two_publishing_daemons_the_one_started_first_keeps_the_machine_id(
    broker: Mosquitto, tmp_path: Path
):
    """An earlier daemon's live birth: this one stands by until its death; a later one's: answered by a re-birth."""
    other = mqtt.Client(CallbackAPIVersion.VERSION2, client_id="other-daemon")
    other.connect("127.0.0.1", broker.port, 30)
    other.loop_start()

    def tell(kind: str, started: float, session: int) -> None:
        instance = {"id": f"other-{started:g}", "host": "elsewhere", "pid": 1, "started": started}
        payload = {"kind": kind, "machine_id": "mill-d", "session": session, "instance": instance}
        other.publish(f"compd/mill-d/{kind}", json.dumps(payload), qos=1).wait_for_publish(WAIT_S)

    def mine(s: Subscriber) -> list[dict[str, object]]:
        return [b for b in s.of("birth") if b["instance"]["pid"] == daemon.pid]

    try:
        with Subscriber(broker.port, "compd/mill-d/+") as sub:
            daemon, log = _start(tmp_path / "d", broker.port)
            sub.wait_for(lambda s: len(mine(s)) == 1, "the daemon's birth")
            tell("birth", 1.0, 5)  # a daemon that started long before this one
            _wait_for_line(log, "telemetry stands by: elsewhere (pid 1)")
            tell("death", 1.0, 5)
            sub.wait_for(lambda s: len(mine(s)) == 2, "the daemon born again, publishing")
            _wait_for_line(log, "telemetry publishes: the other daemon is gone")
            tell("birth", time.time() + 3600, 7)  # one started after it: it keeps on
            sub.wait_for(lambda s: len(mine(s)) == 3, "the daemon's birth, retained again")
            _wait_for_line(log, "it started later and stands by")
    finally:
        other.disconnect()
        other.loop_stop()
        if daemon.poll() is None:
            daemon.kill()
            daemon.wait()
