"""Many machines: a simulated fleet publishing into one real mosquitto, and a broker pulled mid-shift.

Three simulated machines (different seeds and twin variants), each its own
``compd run`` process, publish their telemetry into one mosquitto; one
subscriber checks every machine's birth, statuses and death. Pulling the
broker in the middle of a shift changes nothing in the compensation: the
offsets are those of a run without telemetry, and the counters show the drops.
"""

from __future__ import annotations

import asyncio
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import yaml

from compd.files.yamlplace import resolve_path
from compd.service.compensator import TickRecord
from compd.service.config import Config, load_config
from compd.service.daemon import Service
from compd.sim.plc.machine import SimulatedMachine
from compd.sim.plc.run import run_simulation
from tests.mosquitto import WAIT_S, Mosquitto, Subscriber, free_port, mosquitto_binary

pytestmark = pytest.mark.skipif(
    mosquitto_binary() is None,
    reason="mosquitto is not installed: run .ci/install-system-packages",
)

SIMULATED = resolve_path("bundled:simulated.yaml", Path("."))
MODEL = resolve_path("bundled:simulated_model.yaml", Path("."))
#: (machine_id, seed, variant) of the fleet's three machines.
FLEET = [("mill-a", 11, "reference"), ("mill-b", 12, "spindle-head"), ("mill-c", 13, "long-nose")]
FLEET_SHIFT_S = 600
EVERY_TICKS = 20
#: The shift of the broker-pull test, the ticks at which the broker goes and comes back.
PULL_SHIFT_S, PULLED_AT, BACK_AT = 1200, 400, 900


@pytest.fixture
def broker(tmp_path: Path) -> Iterator[Mosquitto]:
    folder = tmp_path / "broker"
    folder.mkdir()
    mosquitto = Mosquitto(folder).start()
    yield mosquitto
    mosquitto.stop()


def machine_config(
    directory: Path, *, simulation: dict[str, Any], telemetry: dict[str, Any] | None
) -> Config:
    """The bundled simulated machine on a free port, its files under ``directory``."""
    directory.mkdir(parents=True, exist_ok=True)
    doc: dict[str, Any] = yaml.safe_load(SIMULATED.read_text())
    doc["model"] = str(MODEL)
    doc["drivers"]["plc"]["settings"]["port"] = free_port()
    doc["state"] = {"directory": str(directory / "state")}
    doc["recorder"] = {"enabled": False}
    doc["control_socket"] = str(directory / "c.sock")
    doc["simulation"] = simulation
    if telemetry is not None:
        doc["telemetry"] = telemetry
    path = directory / "compd.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return load_config(path)


@dataclass
class Machine:
    machine_id: str
    config: Config
    process: subprocess.Popen[bytes] | None = None


@pytest.fixture
def fleet(broker: Mosquitto, tmp_path: Path) -> Iterator[list[Machine]]:
    """Three simulated machines, each with its own config, publishing into ``broker``; not yet running."""
    machines = []
    for machine_id, seed, variant in FLEET:
        simulation = {"scenario": "production", "hours": 1, "seed": seed, "variant": variant}
        telemetry = {
            "machine_id": machine_id,
            "host": "127.0.0.1",
            "port": broker.port,
            "every_ticks": EVERY_TICKS,
        }
        config = machine_config(tmp_path / machine_id, simulation=simulation, telemetry=telemetry)
        machines.append(Machine(machine_id, config))
    yield machines
    for machine in machines:
        if machine.process is not None and machine.process.poll() is None:
            machine.process.kill()
            machine.process.wait()


def start(machine: Machine, *args: str) -> None:
    """``compd run`` on the machine's config, a child process of its own."""
    log = machine.config.path.parent / "compd.log"
    command = [sys.executable, "-m", "compd.cli", "run", "--config", str(machine.config.path)]
    machine.process = subprocess.Popen(
        [*command, *args], stdout=log.open("wb"), stderr=subprocess.STDOUT
    )


def test_a_fleet_of_three_is_born_reports_and_dies(fleet: list[Machine], broker: Mosquitto):
    """Every machine's retained birth, a status every 20 ticks with nothing lost, a clean death."""
    with Subscriber(broker.port, "compd/#") as sub:
        for machine in fleet:
            start(machine, "--time-scale", "max", "--duration-s", str(FLEET_SHIFT_S))
        for machine in fleet:
            assert machine.process is not None
            code = machine.process.wait(timeout=WAIT_S * 4)
            log = (machine.config.path.parent / "compd.log").read_text()
            assert code == 0, log[-3000:]
        sub.wait_for(lambda s: len(s.of("death")) == len(fleet), "every machine's death")

    statuses_per_machine = (FLEET_SHIFT_S + 1) // EVERY_TICKS
    finals = {}
    for machine in fleet:
        name = machine.machine_id
        births, deaths = sub.of("birth", name), sub.of("death", name)
        statuses = sub.of("status", name)
        assert len(births) == 1 and births[0]["signals"] and births[0]["axes"], name
        assert len(deaths) == 1 and deaths[0]["reason"] == "stopped", name
        assert deaths[0]["session"] == births[0]["session"]
        assert deaths[0]["ticks"] == FLEET_SHIFT_S + 1
        assert deaths[0]["telemetry"]["dropped"] == 0, (
            f"{name}: nothing lost while the broker is up"
        )
        assert len(statuses) == statuses_per_machine, name
        assert [s["counters"]["ticks"] for s in statuses] == [
            EVERY_TICKS * (k + 1) for k in range(statuses_per_machine)
        ]
        finals[name] = statuses[-1]["offsets_um"]["Z"]
    assert len(set(finals.values())) == len(fleet), "three machines, three thermal histories"


@pytest.mark.skip(reason="the roll-out (a model loaded remotely on every machine) comes later")
def test_a_roll_out_reaches_every_machine(fleet: list[Machine], broker: Mosquitto):
    """Hook for the roll-out: one model sent to the fleet is loaded and switched in on every machine.

    What the telemetry already gives it to check, per machine: an ``event``
    ``model_loaded`` (accepted and installed), then ``model_switched``, then
    a new retained ``birth`` whose ``model.sha256`` is the rolled-out model's.
    Start the machines with ``start(machine, "--time-scale", "60")`` so there
    is time to roll out while they run. On the daemon's side a delivered model
    goes through ``Service.load_model`` (the control socket's ``load``).
    """


def test_pulling_the_broker_changes_nothing_in_the_compensation(tmp_path: Path):
    """Broker killed mid-shift and restarted: the same offsets as without telemetry; drops counted; born again."""
    simulation = {"scenario": "production", "hours": 1, "seed": 21}
    plain = machine_config(tmp_path / "plain", simulation=simulation, telemetry=None)
    reference = _offsets(plain)

    folder = tmp_path / "broker"
    folder.mkdir()
    broker = Mosquitto(folder).start()
    telemetry = {
        "machine_id": "mill-p",
        "host": "127.0.0.1",
        "port": broker.port,
        "queue_size": 100,
        "reconnect_max_s": 1,
    }
    config = machine_config(tmp_path / "telemetry", simulation=simulation, telemetry=telemetry)
    seen: dict[str, Any] = {}

    def pull(service: Service, machine: SimulatedMachine, record: TickRecord) -> None:
        t = service.telemetry
        assert t is not None
        ticks = service.compensator.counters.ticks
        if ticks == 2:
            _wait(lambda: t.counters.connected)
        elif ticks == PULLED_AT:
            # What paho was handed is delivered first: "lost" below means dropped by the outage.
            _wait(lambda: t.counters.acknowledged == t.counters.published)
            _wait(lambda: len(sub.messages) >= t.counters.acknowledged)
            broker.stop()
            _wait(lambda: not t.counters.connected)
            seen["dropped_before"] = t.counters.dropped
        elif ticks == BACK_AT:
            seen["dropped"] = t.counters.dropped
            seen["fault"] = t.fault_active
            broker.start()
            _wait(lambda: t.counters.connected and sub.client.is_connected() and sub.resubscribed)

    try:
        with Subscriber(broker.port, "compd/#") as sub:
            sub.resubscribed = False
            sub.client.on_subscribe = lambda *a: setattr(sub, "resubscribed", True)
            with_telemetry = _offsets(config, on_tick=pull)
            sub.wait_for(lambda s: s.of("death"), "the death")
    finally:
        broker.stop()

    assert with_telemetry == reference, "the offsets do not depend on the broker"
    assert seen["dropped_before"] == 0
    assert seen["dropped"] > 0 and seen["fault"], "the outage is a counted, logged telemetry fault"
    births = sub.of("birth")
    assert len(births) == 2 and births[1]["session"] > births[0]["session"], "born again"
    events = [(e["event"], e["message"]) for e in sub.of("event")]
    assert ("fault", "telemetry broker connection lost") in events
    assert ("reconnected", "telemetry broker connected again") in events
    before = [
        s["counters"]["ticks"] for s in sub.of("status") if s["session"] == births[0]["session"]
    ]
    assert before == list(range(1, len(before) + 1)), "none lost while the broker was up"
    assert sub.of("status")[-1]["counters"]["ticks"] == PULL_SHIFT_S + 1
    assert sub.of("death")[0]["telemetry"]["dropped"] == seen["dropped"]


def _offsets(config: Config, **kwargs: Any) -> list[tuple[float, float, float | None]]:
    """Per tick: time, the offset the stage gave and the one the PLC acknowledged (Z, um)."""
    rows: list[tuple[float, float, float | None]] = []
    on_tick = kwargs.pop("on_tick", None)

    def keep(service: Service, machine: SimulatedMachine, record: TickRecord) -> None:
        acknowledged = record.acknowledged_um["Z"]  # NaN: not written (NaN != NaN: None here)
        rows.append(
            (
                record.t_s,
                record.offsets_um["Z"],
                None if acknowledged != acknowledged else acknowledged,
            )
        )
        if on_tick is not None:
            on_tick(service, machine, record)

    asyncio.run(run_simulation(config, on_tick=keep, duration_s=PULL_SHIFT_S, **kwargs))
    return rows


def _wait(condition: Any) -> None:
    """Block (real time, bounded): virtual time stands still while the network catches up."""
    deadline = time.monotonic() + WAIT_S
    while not condition():
        assert time.monotonic() < deadline, "timed out waiting for the broker"
        time.sleep(0.005)
