"""Many machines: a simulated fleet publishing into one real mosquitto, and a broker pulled mid-shift.

Three simulated machines (different seeds and twin variants), each its own
``compd run`` process, publish their telemetry into one mosquitto; one
subscriber checks every machine's birth, statuses and death. Pulling the
broker in the middle of a shift changes nothing in the compensation: the
offsets are those of a run without telemetry, and the counters show the drops.
"""

from __future__ import annotations

import asyncio
import base64
import hashlib
import json
import re
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import yaml

from compd.cli import main
from compd.cli.args import EXIT_INPUT_ERROR
from compd.cli.rollout import desired_record
from compd.files.equations import tfs_sha256, with_equations
from compd.files.modelfile import parse_model
from compd.service.config.loading import Config
from compd.service.daemon import Service
from compd.service.fleet.remoteload import DESIRED_SCHEMA
from compd.service.loop.compensator import TickRecord
from compd.sim.plc.machine import SimulatedMachine
from compd.sim.plc.run import run_simulation
from tests.mosquitto import (
    MODEL,
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

#: (machine_id, seed, variant) of the fleet's three machines.
FLEET = [("mill-a", 11, "reference"), ("mill-b", 12, "spindle-head"), ("mill-c", 13, "long-nose")]
FLEET_SHIFT_S = 600
EVERY_TICKS = 20
#: The shift of the broker-pull test, the ticks at which the broker goes and comes back.
PULL_SHIFT_S, PULLED_AT, BACK_AT = 1200, 400, 900


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
            "accept_models": True,
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


def test_a_roll_out_reaches_every_machine(
    fleet: list[Machine], broker: Mosquitto, tmp_path: Path, capsys: pytest.CaptureFixture[str]
):
    """One model rolled out to three running machines: each accepts it and switches; sent again, a no-op."""
    new = _variant(tmp_path, "rolled-out.yaml")
    settings = _broker_settings(tmp_path, broker.port)
    with Subscriber(broker.port, "compd/#") as sub:
        _start_and_wait_for_births(fleet, sub)
        code = main(["model", "rollout", str(new), *settings, *ALL, "--wait-blend"])
        table = capsys.readouterr().out
        assert code == 0, table
        for machine in fleet:
            assert _row(table, machine.machine_id)[:2] == ["accepted", "60"], table
            assert _row(table, machine.machine_id)[-2:] == ["yes", "online"], table
        sha256 = hashlib.sha256(new.read_bytes()).hexdigest()
        sub.wait_for(
            lambda s: all(_running(s, m.machine_id) == sha256 for m in fleet),
            "every machine's re-birth naming the rolled-out model",
        )
        for machine in fleet:
            events = [e["event"] for e in sub.of("event", machine.machine_id)]
            assert events.count("model_loaded") == 1 and events.count("model_switched") == 1

        code = main(["model", "rollout", str(new), *settings, *ALL])
        table = capsys.readouterr().out
        assert code == 0, table
        for machine in fleet:
            assert _row(table, machine.machine_id)[:2] == ["already", "running"], table
        events = [e["event"] for e in sub.of("event")]
        assert events.count("model_loaded") == len(fleet), "sent again: nothing loaded"


def test_a_bad_model_is_refused_by_every_machine_and_a_machine_away_does_not_answer(
    fleet: list[Machine], broker: Mosquitto, tmp_path: Path, capsys: pytest.CaptureFixture[str]
):
    """Unstable model: refused here before sending, and by every machine when sent; a stopped one: no answer."""
    bad = _variant(tmp_path, "bad.yaml", unstable=True)
    settings = _broker_settings(tmp_path, broker.port)
    with Subscriber(broker.port, "compd/#") as sub:
        _start_and_wait_for_births(fleet, sub)
        assert main(["model", "rollout", str(bad), *settings, *ALL]) == EXIT_INPUT_ERROR
        assert "unstable:" in capsys.readouterr().err
        assert not [m for m in sub.messages if "/cmd/" in m.topic], "refused before sending"

        code = main(["model", "rollout", str(bad), *settings, *ALL, "--no-local-check"])
        table = capsys.readouterr().out
        assert code == 1, table
        for machine in fleet:
            assert _row(table, machine.machine_id)[0] == "refused", table
        assert table.count("unstable:") >= len(fleet), "the reason, per machine"
        refused = [e for e in sub.of("event") if e["event"] == "model_refused"]
        assert len(refused) == len(fleet)
        assert all(_running(sub, m.machine_id) == _running(sub, "mill-a") for m in fleet)

        away = fleet[2]
        assert away.process is not None
        away.process.terminate()
        assert away.process.wait(timeout=WAIT_S) == 0
        sub.wait_for(lambda s: s.of("death", away.machine_id), "the stopped machine's death")
        new = _variant(tmp_path, "rolled-out.yaml")
        code = main(["model", "rollout", str(new), *settings, *ALL, "--timeout-s", "5"])
        table = capsys.readouterr().out
        assert code == 1, table
        row = _row(table, away.machine_id)
        assert row[0] == "pending" and row[-2:] == ["offline", "(stopped)"], table
        assert "takes the desired model itself when it is back" in table
        for machine in fleet[:2]:
            assert _row(table, machine.machine_id)[0] == "accepted", table


def test_only_the_roll_out_user_can_send_a_model_over_tls(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
):
    """Per-machine users and an ACL over TLS: another machine or a user without the right is never heard."""
    pki = make_pki(tmp_path)
    passwords = tmp_path / "mosquitto.passwd"
    users = ["mill-a", "mill-b", "rollout", "viewer"]
    for k, user in enumerate(users):
        create = ["-c"] if k == 0 else []
        subprocess.run(
            ["mosquitto_passwd", *create, "-b", str(passwords), user, f"{user}-pw"],
            check=True,
            capture_output=True,
        )
        (tmp_path / f"{user}.password").write_text(f"{user}-pw\n")
    acl = tmp_path / "mosquitto.acl"
    acl.write_text(ACL)
    secure = free_port()
    folder = tmp_path / "broker"
    folder.mkdir()
    broker = Mosquitto(
        folder,
        extra=[
            f"listener {secure} 127.0.0.1",
            f"cafile {pki.ca}",
            f"certfile {pki.server_cert}",
            f"keyfile {pki.server_key}",
            "allow_anonymous false",
            f"password_file {passwords}",
            f"acl_file {acl}",
        ],
    ).start()
    tls = {"ca_file": str(pki.ca)}
    machines = []
    for machine_id, seed, variant in FLEET[:2]:
        telemetry = {
            "machine_id": machine_id,
            "host": "127.0.0.1",
            "port": secure,
            "username": machine_id,
            "password_file": str(tmp_path / f"{machine_id}.password"),
            "tls": tls,
            "every_ticks": EVERY_TICKS,
            "accept_models": True,
        }
        simulation = {"scenario": "production", "hours": 1, "seed": seed, "variant": variant}
        config = machine_config(tmp_path / machine_id, simulation=simulation, telemetry=telemetry)
        machines.append(Machine(machine_id, config))

    def as_user(user: str) -> list[str]:
        section = {
            "host": "127.0.0.1",
            "port": secure,
            "username": user,
            "password_file": f"{user}.password",
            "tls": tls,
        }
        path = tmp_path / f"{user}-broker.yaml"
        path.write_text(yaml.safe_dump({"telemetry": section}))
        return ["--broker-config", str(path)]

    new = _variant(tmp_path, "rolled-out.yaml")
    try:
        with Subscriber(broker.port, "compd/#") as sub:  # on the plain listener: hears everything
            _start_and_wait_for_births(machines, sub)
            (tmp_path / "intruder.password").write_text("guess\n")
            code = main(
                ["model", "rollout", str(new), *as_user("intruder"), "--machines", "mill-a"]
            )
            assert code == EXIT_INPUT_ERROR
            assert "refused the login" in capsys.readouterr().err
            # A machine's own user cannot command it either (a retained command left by it
            # would be loaded again at every restart): only the roll-out user writes cmd/. Nor
            # may it write desired records: refused there, before any command is sent.
            for user, target in (
                ("viewer", "mill-a,mill-b"),
                ("mill-b", "mill-a"),
                ("mill-a", "mill-a"),
            ):
                rollout = ["model", "rollout", str(new), *as_user(user), "--timeout-s", "3"]
                code = main([*rollout, "--machines", target])
                err = capsys.readouterr().err
                assert code == EXIT_INPUT_ERROR, err
                assert "refused this user's message" in err and "compd/+/desired" in err, err
            assert not [m for m in sub.messages if "/cmd/" in m.topic], (
                "the broker passed nothing on"
            )
            loads = [e for e in sub.of("event") if e["event"].startswith("model_")]
            assert not sub.of("reply") and not loads, "nothing delivered, nothing loaded"

            rollout = ["model", "rollout", str(new), *as_user("rollout"), "--wait-blend"]
            code = main([*rollout, "--machines", "mill-a,mill-b"])
            table = capsys.readouterr().out
            assert code == 0, table
            for machine in machines:
                row = _row(table, machine.machine_id)
                assert row[0] == "accepted" and row[-2:] == ["yes", "online"], table
    finally:
        for machine in machines:
            if machine.process is not None and machine.process.poll() is None:
                machine.process.kill()
                machine.process.wait()
        broker.stop()


#: The broker's ACL for a fleet, as deploy/README.md ("The MQTT broker") gives it: each machine,
#: logged in as its machine_id, reads its own commands and writes its own topics but not commands;
#: only the roll-out user writes commands, and reads the answers, events, births and deaths.
GUIDE_ACL = re.search(
    r"```text\n(# /etc/mosquitto/compd\.acl\n.*?)```",
    (Path(__file__).parents[2] / "deploy" / "README.md").read_text(),
    re.S,
)
assert GUIDE_ACL is not None, "deploy/README.md has no /etc/mosquitto/compd.acl block"
ACL = GUIDE_ACL[1]
ALL = ["--machines", ",".join(machine_id for machine_id, _, _ in FLEET)]


def _variant(folder: Path, name: str, *, unstable: bool = False) -> Path:
    """The machines' model with one more comment line (a new sha256), or with an unstable pole.

    Unstable: the first sub-model's denominator, in its TF and in the difference equations the
    machines step, has poles 2 and 0.5, and the equations' ``tfs_sha256`` is the edited TFs', so
    what a machine refuses is the pole (not equations derived from other TFs).
    """
    text = MODEL.read_text() + "\n# rolled out to the fleet\n"
    if unstable:
        unstable_den = "den: [1.0, -2.5, 1.0]"
        head, section, equations = text.partition("difference_equations:")
        head, replaced = re.subn(r"den: \[[^\]]*\]", unstable_den, head, count=1)
        equations, also = re.subn(r"den: \[[^\]]*\]", unstable_den, equations, count=1)
        assert replaced == also == 1
        digest = tfs_sha256(parse_model(with_equations(head + section + equations, [])).model)
        equations = re.sub(r'tfs_sha256: "[0-9a-f]{64}"', f'tfs_sha256: "{digest}"', equations)
        text = head + section + equations
    path = folder / name
    path.write_text(text)
    return path


def _broker_settings(folder: Path, port: int) -> list[str]:
    path = folder / "broker.yaml"
    path.write_text(yaml.safe_dump({"host": "127.0.0.1", "port": port}))
    return ["--broker-config", str(path), "--timeout-s", str(WAIT_S)]


def _start_and_wait_for_births(machines: list[Machine], sub: Subscriber) -> None:
    """Start each machine at 60x (a blend of 60 s takes 1 s) and wait until all are born."""
    for machine in machines:
        start(machine, "--time-scale", "60", "--duration-s", "36000")
    sub.wait_for(
        lambda s: all(s.of("birth", m.machine_id) for m in machines), "every machine's birth"
    )


def _running(sub: Subscriber, machine_id: str) -> str:
    """The sha256 of the model the machine's latest birth names."""
    births = sub.of("birth", machine_id)
    return births[-1]["model"]["sha256"] if births else ""


def _row(table: str, machine_id: str) -> list[str]:
    """The words of the machine's row in the roll-out's table, after its name."""
    for line in table.splitlines():
        words = line.replace("│", " ").replace("┃", " ").split()
        if words and words[0] == machine_id:
            return words[1:]
    raise AssertionError(f"no row for {machine_id} in:\n{table}")


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
            # Publishing, not only connected: until its SUBACK says no rival holds the machine_id
            # the telemetry only queues, and every tick would drop one more from the full queue.
            _wait(lambda: t.publishing and sub.client.is_connected() and sub.resubscribed)
        elif ticks > BACK_AT:
            # The network keeps up with virtual time: a loaded host's slow acknowledgements
            # would otherwise refill the queue while the backlog waits for them, and drop.
            _wait(lambda: t.counters.acknowledged == t.counters.published)

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


def test_a_machine_away_is_not_waited_for_and_takes_the_desired_model_when_back(
    fleet: list[Machine], broker: Mosquitto, tmp_path: Path, capsys: pytest.CaptureFixture[str]
):
    """Offline at the roll-out: pending at once, not after --timeout-s; back, it loads its desired record."""
    new = _variant(tmp_path, "rolled-out.yaml")
    sha256 = hashlib.sha256(new.read_bytes()).hexdigest()
    settings = _broker_settings(tmp_path, broker.port)
    listed = tmp_path / "machines.txt"
    listed.write_text("# the fleet\nmill-a\nmill-b  # spindle head\nmill-c\n")
    with Subscriber(broker.port, "compd/#") as sub:
        _start_and_wait_for_births(fleet, sub)
        away = fleet[2]
        assert away.process is not None
        away.process.terminate()
        assert away.process.wait(timeout=WAIT_S) == 0
        sub.wait_for(lambda s: s.of("death", away.machine_id), "the stopped machine's death")

        timeout_s = 10 * WAIT_S  # waited for all of it, the test would take 15 minutes
        rollout = ["model", "rollout", str(new), *settings, "--machines", f"@{listed}"]
        began = time.monotonic()
        code = main([*rollout, "--wait-blend", "--json", "--timeout-s", str(timeout_s)])
        took_s = time.monotonic() - began
        report = json.loads(capsys.readouterr().out)
        assert code == 1, report
        assert took_s < timeout_s, "the machine the broker says is offline was not waited for"
        rows = {row["machine_id"]: row for row in report["machines"]}
        assert rows["mill-c"]["result"] == "pending", rows["mill-c"]
        assert rows["mill-c"]["presence"] == "offline (stopped)"
        assert "takes the desired model itself when it is back" in rows["mill-c"]["reason"]
        assert not [m for m in sub.messages if m.topic == "compd/mill-c/cmd/model_load"]
        for machine in fleet[:2]:
            row = rows[machine.machine_id]
            assert row["result"] == "accepted" and row["blended_in"] is True, row
            blended = [
                e
                for e in sub.of("event", machine.machine_id)
                if e["event"] == "model_blended" and e["details"]["sha256"] == sha256
            ]
            assert blended, "blended in: yes only once its blend ended"

        start(away, "--time-scale", "60", "--duration-s", "36000")
        sub.wait_for(lambda s: _running(s, away.machine_id) == sha256, "mill-c back, running it")
        # The switch is told after the status that names the model: wait for its event too.
        sub.wait_for(
            lambda s: "model_switched" in [e["event"] for e in s.of("event", away.machine_id)],
            "mill-c's model_switched event",
        )
        events = [e["event"] for e in sub.of("event", away.machine_id)]
        assert "model_loaded" in events and "model_switched" in events, events
        sub.wait_for(
            lambda s: s.of("birth", away.machine_id)[-1]["desired_model"]["runs_it"] is True,
            "mill-c's birth saying it runs its desired model",
        )

        code = main(["model", "rollout", "--pending", *settings, "--json"])
        report = json.loads(capsys.readouterr().out)
        assert code == 0, report
        assert [row["result"] for row in report["machines"]] == ["up_to_date"] * 3


def test_pending_sends_an_online_machine_the_desired_model_it_does_not_run(
    fleet: list[Machine], broker: Mosquitto, tmp_path: Path, capsys: pytest.CaptureFixture[str]
):
    """A desired record written while the machine is online (no command followed): --pending sends it."""
    new = _variant(tmp_path, "rolled-out.yaml")
    raw = new.read_bytes()
    sha256 = hashlib.sha256(raw).hexdigest()
    settings = _broker_settings(tmp_path, broker.port)
    machine = fleet[1]
    with Subscriber(broker.port, "compd/#") as sub:
        _start_and_wait_for_births([machine], sub)
        request = {"name": "rolled-out.yaml", "model_base64": base64.b64encode(raw).decode()}
        request |= {"sha256": sha256, "requested_by": "test", "sent_unix_s": time.time()}
        writer = Subscriber(broker.port, "nothing/#")
        with writer:
            topic = f"compd/{machine.machine_id}/desired"
            writer.client.publish(
                topic, desired_record(request), qos=1, retain=True
            ).wait_for_publish(WAIT_S)
        sub.wait_for(
            lambda s: (
                (s.of("birth", machine.machine_id)[-1].get("desired_model") or {}).get("sha256")
                == sha256
            ),
            "the machine naming its desired model",
        )
        assert _running(sub, machine.machine_id) != sha256, "a live record is not taken by itself"

        code = main(["model", "rollout", "--pending", *settings, "--wait-blend", "--json"])
        report = json.loads(capsys.readouterr().out)
        assert code == 0, report
        (row,) = report["machines"]
        assert row["result"] == "accepted" and row["blended_in"] is True, row
        sub.wait_for(lambda s: _running(s, machine.machine_id) == sha256, "running it")


def test_a_machine_back_refuses_a_bad_desired_model_and_runs_on(
    fleet: list[Machine], broker: Mosquitto, tmp_path: Path, capsys: pytest.CaptureFixture[str]
):
    """An unstable model left as desired for a machine away: back, it refuses it once, keeps its model."""
    bad = _variant(tmp_path, "bad.yaml", unstable=True)
    settings = _broker_settings(tmp_path, broker.port)
    with Subscriber(broker.port, "compd/#") as sub:
        away = fleet[0]
        _start_and_wait_for_births([away], sub)
        running = _running(sub, away.machine_id)
        assert away.process is not None
        away.process.terminate()
        assert away.process.wait(timeout=WAIT_S) == 0
        sub.wait_for(lambda s: s.of("death", away.machine_id), "the stopped machine's death")
        rollout = ["model", "rollout", str(bad), *settings, "--machines", away.machine_id]
        code = main([*rollout, "--no-local-check", "--json"])
        report = json.loads(capsys.readouterr().out)
        assert code == 1 and report["machines"][0]["result"] == "pending", report

        start(away, "--time-scale", "60", "--duration-s", "36000")
        sub.wait_for(
            lambda s: any(e["event"] == "model_refused" for e in s.of("event", away.machine_id)),
            "the machine back refusing its desired model",
        )
        refused = [e for e in sub.of("event", away.machine_id) if e["event"] == "model_refused"]
        assert refused[0]["message"] == "desired model refused"
        assert "unstable:" in refused[0]["details"]["reason"], refused[0]
        assert _running(sub, away.machine_id) == running, "the running model untouched"
        assert not [e for e in sub.of("event", away.machine_id) if e["event"] == "model_loaded"]


def test_a_canary_that_refuses_stops_the_roll_out_to_every_machine_online(
    fleet: list[Machine], broker: Mosquitto, tmp_path: Path, capsys: pytest.CaptureFixture[str]
):
    """``--online --canary 1``: the first machine refuses, the others are not sent it; a good model reaches all."""
    bad = _variant(tmp_path, "bad.yaml", unstable=True)
    good = _variant(tmp_path, "rolled-out.yaml")
    settings = _broker_settings(tmp_path, broker.port)
    with Subscriber(broker.port, "compd/#") as sub:
        _start_and_wait_for_births(fleet, sub)
        waves = ["--online", "--canary", "1", "--json"]
        code = main(["model", "rollout", str(bad), *settings, *waves, "--no-local-check"])
        report = json.loads(capsys.readouterr().out)
        assert code == 1, report
        rows = {row["machine_id"]: row for row in report["machines"]}
        assert sorted(rows) == ["mill-a", "mill-b", "mill-c"], "every machine online"
        assert rows["mill-a"]["result"] == "refused"
        for name in ("mill-b", "mill-c"):
            assert rows[name]["result"] == "not_sent", rows[name]
            assert "canary mill-a refused" in rows[name]["reason"]
        sent = {m.topic.split("/")[1] for m in sub.messages if "/cmd/" in m.topic}
        assert sent == {"mill-a"}, "the rest never sent it"
        desired = {
            m.topic.split("/")[1]
            for m in sub.messages
            if m.topic.endswith("/desired") and m.payload.get("schema") == DESIRED_SCHEMA
        }
        assert desired == {"mill-a"}, "nor left a desired record for --pending to send later"

        code = main(["model", "rollout", str(good), *settings, *waves, "--wait-blend"])
        report = json.loads(capsys.readouterr().out)
        assert code == 0, report
        assert [row["result"] for row in report["machines"]] == ["accepted"] * 3
