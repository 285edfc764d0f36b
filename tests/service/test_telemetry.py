"""MQTT telemetry against a real mosquitto: birth, status, events and death, TLS and a password, a broker pulled.

Each test starts its own mosquitto on a free port and runs compd's service,
unchanged, against the simulated machine on virtual time; a paho subscriber
keeps what the broker delivers.
"""

from __future__ import annotations

import asyncio
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
import structlog.testing

from compd.errors import ConfigFileError
from compd.service.config.loading import Config
from compd.service.control.modelload import load_slot
from compd.service.daemon import Service
from compd.service.loop.compensator import TickRecord
from compd.sim.plc.machine import SimulatedMachine
from compd.sim.plc.run import SimulationResult, run_simulation
from tests.mosquitto import (
    WAIT_S,
    Mosquitto,
    Subscriber,
    free_port,
    machine_config,
    make_pki,
    mosquitto_binary,
)

pytestmark = pytest.mark.skipif(
    mosquitto_binary() is None,
    reason="mosquitto is not installed: run .ci/install-system-packages",
)


def simulate(config: Config, duration_s: float, **kwargs: Any) -> SimulationResult:
    return asyncio.run(run_simulation(config, duration_s=duration_s, **kwargs))


def test_birth_status_events_and_death_reach_a_subscriber(broker: Mosquitto, tmp_path: Path):
    """One run: a retained birth, a status every N ticks, fault/reconnect/model events, a retained death."""
    telemetry = {
        "machine_id": "mill-1",
        "host": "127.0.0.1",
        "port": broker.port,
        "every_ticks": 10,
    }
    faults = [
        # On a model input with no second sensor: its prediction from the others stands in.
        {"kind": "nan", "signal": "T_headstock_degC", "at_s": 60, "duration_s": 60},
        {"kind": "drop", "driver": "plc", "at_s": 200, "duration_s": 10},
    ]
    config = machine_config(
        tmp_path / "run",
        telemetry=telemetry,
        simulation={"scenario": "production", "hours": 1, "seed": 3, "faults": faults},
    )

    records: dict[float, TickRecord] = {}

    def reload(service: Service, machine: SimulatedMachine, record: TickRecord) -> None:
        records[record.t_s] = record
        ticks = service.compensator.counters.ticks
        if ticks == 2:  # the broker must hear the run: the connection is made in real time
            wait_until(
                lambda: service.telemetry is not None and service.telemetry.counters.connected
            )
        if ticks == 250:  # the same model again: a switch, blended
            service.compensator.load(load_slot(config, config.model_path, record.wall_unix_s))

    with Subscriber(broker.port, "compd/#") as sub, structlog.testing.capture_logs() as logs:
        result = simulate(config, 300, on_tick=reload)
        sub.wait_for(lambda s: s.of("death", "mill-1"), "the death")

    births, deaths = sub.of("birth"), sub.of("death")
    statuses = sub.of("status", "mill-1")
    assert births[0]["machine_id"] == "mill-1" and births[0]["schema"] == "compd.telemetry/1"
    assert births[0]["model"]["name"] and births[0]["signals"]["T_spindle_degC"]["unit"] == "degC"
    assert births[0]["axes"]["Z"]["model_output"] == "disp_z_um"
    assert len(births) == 2, "born once on connection, again when the model switched"
    assert deaths == [deaths[0]] and deaths[0]["reason"] == "stopped"
    assert deaths[0]["session"] == births[0]["session"]
    assert deaths[0]["telemetry"]["dropped"] == 0
    # Every 10th of the 301 ticks (0 s, 1 s, ... 300 s): the 10th is at 9 s.
    assert [s["t_s"] for s in statuses] == [float(t) for t in range(9, 300, 10)]
    last = statuses[-1]
    assert set(last["inputs"]) == set(config.doc.signals)
    assert last["inputs"]["T_spindle_degC"]["health"] == "ok"
    assert last["offsets_um"] == records[last["t_s"]].offsets_um
    assert last["acknowledged_um"] == records[last["t_s"]].acknowledged_um
    assert last["written"] is True
    assert isinstance(last["status_word"], int) and "disp_z_um" in last["model_outputs"]
    # The NaN on a model input is stood in for by its prediction from the others: no fault.
    assert last["counters"]["ticks"] == 300 and last["counters"]["signal_faults"] == 0
    assert last["counters"]["signal_estimates"] == 1
    events = sub.of("event", "mill-1")
    kinds = [(e["event"], e["message"]) for e in events]
    assert ("fault", "signal replaced by its prediction from the other sensors") in kinds
    assert ("cleared", "signal agrees with the other sensors again: its readings are used") in kinds
    assert ("fault", "driver read failed") in kinds or ("fault", "driver write failed") in kinds
    assert ("reconnected", "driver reconnected") in kinds
    assert ("model_switched", "model switched in") in kinds
    # Each event is in the local log too (the journal), a fault at WARNING or above.
    logged = {(line["event"], line["log_level"]) for line in logs}
    for kind, message in kinds:
        levels = {"warning", "error", "critical"} | (set() if kind == "fault" else {"info"})
        assert any((message, level) in logged for level in levels), (kind, message)
    seqs = [m.payload["seq"] for m in sub.messages]
    assert seqs == sorted(seqs), "one session's messages arrive in order"
    assert result.status["telemetry"]["published"] == len(sub.messages)

    with Subscriber(broker.port, "compd/mill-1/+") as late:  # a dashboard started afterwards
        late.wait_for(lambda s: len(s.messages) >= 2, "the retained birth and death")
    retained = {m.topic: m for m in late.messages}
    assert retained["compd/mill-1/birth"].retained and retained["compd/mill-1/death"].retained


def wait_until(condition: Any) -> None:
    """Block (real time, bounded) until ``condition()``: virtual time waits for the network."""
    deadline = time.monotonic() + WAIT_S
    while not condition():
        assert time.monotonic() < deadline, "timed out waiting for the telemetry"
        time.sleep(0.005)


def test_killed_daemon_leaves_its_last_will(broker: Mosquitto, tmp_path: Path):
    """SIGKILL of ``compd run``: the broker publishes the retained death, ``connection lost``, same session, stamped."""
    telemetry = {"machine_id": "mill-k", "host": "127.0.0.1", "port": broker.port, "every_ticks": 1}
    config = machine_config(tmp_path / "run", telemetry=telemetry)
    log = tmp_path / "compd.log"
    command = [sys.executable, "-m", "compd.cli", "run", "--config", str(config.path)]
    command += ["--time-scale", "10"]
    with Subscriber(broker.port, "compd/mill-k/+") as sub:
        daemon = subprocess.Popen(command, stdout=log.open("wb"), stderr=subprocess.STDOUT)
        try:
            sub.wait_for(lambda s: len(s.of("status")) >= 3, "three statuses of the daemon")
        finally:
            os.kill(daemon.pid, signal.SIGKILL)
            daemon.wait()
        sub.wait_for(lambda s: s.of("death"), "the last will")
    birth, death = sub.of("birth")[0], sub.of("death")[0]
    assert death["reason"] == "connection lost"
    assert death["session"] == birth["session"]
    assert death["time_is"] == "connected" and 0 < death["time"] <= birth["time"]
    assert death["instance"] == birth["instance"] and death["instance"]["pid"] == daemon.pid


def test_tls_and_a_password_file(tmp_path: Path):
    """TLS with a client certificate and a password from a file: born; a wrong password is a telemetry fault."""
    pki = make_pki(tmp_path)
    passwords = tmp_path / "mosquitto.passwd"
    subprocess.run(
        ["mosquitto_passwd", "-c", "-b", str(passwords), "compd", "s3cret"],
        check=True,
        capture_output=True,
    )
    secure = free_port()
    broker = Mosquitto(
        tmp_path,
        extra=[
            f"listener {secure} 127.0.0.1",
            f"cafile {pki.ca}",
            f"certfile {pki.server_cert}",
            f"keyfile {pki.server_key}",
            "require_certificate true",
            "allow_anonymous false",
            f"password_file {passwords}",
        ],
    ).start()
    (tmp_path / "password").write_text("s3cret\n")
    (tmp_path / "wrong-password").write_text("guess\n")
    telemetry = {
        "machine_id": "mill-tls",
        "host": "127.0.0.1",
        "port": secure,
        "username": "compd",
        "password_file": str(tmp_path / "password"),
        "tls": {"ca_file": str(pki.ca), "cert_file": str(pki.client_cert), "key_file": str(pki.client_key)},
    }  # fmt: skip

    def connected(service: Service, machine: SimulatedMachine, record: TickRecord) -> None:
        if service.compensator.counters.ticks == 2:
            t = service.telemetry
            assert t is not None
            wait_until(lambda: t.counters.connected or t.fault_active)

    try:
        with Subscriber(broker.port, "compd/#") as sub:  # on the plain listener
            good = machine_config(tmp_path / "good", telemetry=telemetry)
            simulate(good, 30, on_tick=connected)
            sub.wait_for(lambda s: s.of("death"), "the secured daemon's death")
            assert sub.of("birth")[0]["machine_id"] == "mill-tls"
            wrong = machine_config(
                tmp_path / "wrong",
                telemetry=telemetry | {"password_file": str(tmp_path / "wrong-password")},
            )
            result = simulate(wrong, 30, on_tick=connected)
    finally:
        broker.stop()
    assert result.status["telemetry"]["connected"] is False
    assert result.status["counters"]["ticks"] == 31, "the compensation ran on regardless"
    assert len(sub.of("birth")) == 1, "refused: never born"


def test_a_missing_password_file_stops_the_start(tmp_path: Path):
    """A telemetry file that cannot be read is a config error naming the key, before any I/O."""
    with pytest.raises(ConfigFileError) as caught:
        machine_config(
            tmp_path,
            telemetry={"machine_id": "m", "username": "u", "password_file": "nowhere.txt"},
        )
    text = str(caught.value)
    assert "telemetry.password_file" in text and "nowhere.txt" in text


def test_a_machine_id_with_a_wildcard_is_refused(tmp_path: Path):
    """``machine_id`` is one topic level: '#', '+' or '/' are config errors."""
    with pytest.raises(ConfigFileError, match="machine_id"):
        machine_config(tmp_path, telemetry={"machine_id": "mill/#"})


def test_no_broker_at_all_is_a_telemetry_fault_only(tmp_path: Path):
    """Nothing listening: the shift runs as without telemetry, the queue drops its oldest and counts them."""
    telemetry = {"machine_id": "mill-x", "host": "127.0.0.1", "port": free_port(), "queue_size": 10}
    config = machine_config(tmp_path, telemetry=telemetry)

    def unreachable(service: Service, machine: SimulatedMachine, record: TickRecord) -> None:
        if service.compensator.counters.ticks == 2:
            t = service.telemetry
            assert t is not None
            wait_until(lambda: t.fault_active)

    result = simulate(config, 30, on_tick=unreachable)
    assert result.status["counters"]["ticks"] == 31
    assert result.status["telemetry"] == {
        "connected": False, "published": 0, "acknowledged": 0, "dropped": 21, "connections": 0,
        "stands_by_for": None,
    }  # fmt: skip
