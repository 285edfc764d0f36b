"""A shop's broker: 150 machines' retained births, deaths and desired records, all read by the fleet tools.

A broker hands a subscription's retained messages out after its SUBACK, at
most its in-flight window (mosquitto: 20) at a time; the tools read until a
marker they publish after subscribing comes back. The records are written
here by one MQTT client as the daemons and the roll-out write them (a
birth per machine; a clean death or a last will newer than the birth for
some; a desired record for most), into a real mosquitto; ``compd model
rollout --pending``, ``--online`` and ``compd fleet list`` must see every one.
"""

from __future__ import annotations

import base64
import hashlib
import json
from pathlib import Path

import paho.mqtt.client as mqtt
import pytest
import yaml
from paho.mqtt.enums import CallbackAPIVersion

from compd.cli import main
from compd.cli.args import EXIT_INPUT_ERROR
from compd.cli.rollout import broker_section
from compd.cli.rolloutpending import online
from tests.mosquitto import WAIT_S, Mosquitto, mosquitto_binary

pytestmark = pytest.mark.skipif(
    mosquitto_binary() is None,
    reason="mosquitto is not installed: run .ci/install-system-packages",
)

MACHINES = 150
#: Machine k: online unless k % 5 == 1 (a clean stop) or k % 5 == 2 (its last will).
STOPPED, LOST = 1, 2
#: Births that say the daemon takes no models (k % 10 == 6), or nothing (k % 10 == 7: an older compd).
#: Machines without a desired record (k % 10 == 9), and desired records of machines never born.
UNBORN = ["new-1", "new-2", "new-3"]
MODEL = b"# a model file's bytes\n"
SHA256 = hashlib.sha256(MODEL).hexdigest()
OLD_SHA256 = "0" * 64
BORN_UNIX_S = 1_790_000_000.0


def name(k: int) -> str:
    return f"m{k:03d}"


def state(k: int) -> str:
    return {STOPPED: "offline (stopped)", LOST: "offline (connection lost)"}.get(k % 5, "online")


def records() -> list[tuple[str, dict[str, object]]]:
    """(topic, payload) of every retained record: births, deaths, desired records."""
    out: list[tuple[str, dict[str, object]]] = []
    desired = {
        "schema": "compd.desired_model/1",
        "rollout_id": "r1",
        "name": "twin-z.yaml",
        "model_base64": base64.b64encode(MODEL).decode(),
        "sha256": SHA256,
        "requested_by": "test@here",
        "sent_unix_s": BORN_UNIX_S,
    }
    for k in range(MACHINES):
        machine = name(k)
        instance = {"id": f"i{k}", "host": f"host-{k}", "pid": 1000 + k, "started": BORN_UNIX_S}
        # The online ones run the desired model (up to date); the offline ones an older one.
        sha = SHA256 if state(k) == "online" else OLD_SHA256
        header = {"schema": "compd.telemetry/1", "machine_id": machine, "session": 5 + k}
        birth = header | {"kind": "birth", "time": BORN_UNIX_S + k, "instance": instance}
        birth |= {"model": {"name": "twin-z", "sha256": sha}}
        birth |= {} if k % 10 == 7 else {"commands": [] if k % 10 == 6 else ["model_load"]}
        out.append((f"compd/{machine}/birth", birth))
        if k % 5 == STOPPED:
            death = header | {"kind": "death", "time": BORN_UNIX_S + k + 600, "reason": "stopped"}
            out.append((f"compd/{machine}/death", death | {"instance": instance}))
        elif k % 5 == LOST:
            will = header | {"kind": "death", "time": BORN_UNIX_S + k, "reason": "connection lost"}
            out.append((f"compd/{machine}/death", will | {"instance": instance}))
        elif k % 5 == 3:  # an older session's death: online all the same
            old = header | {"kind": "death", "session": 4 + k, "reason": "stopped"}
            out.append((f"compd/{machine}/death", old | {"instance": instance}))
        if k % 10 != 9:
            out.append((f"compd/{machine}/{'desired'}", desired))
    out += [(f"compd/{machine}/desired", desired) for machine in UNBORN]
    return out


@pytest.fixture
def shop(broker: Mosquitto, tmp_path: Path) -> list[str]:
    """The broker holding every record (each acknowledged); the tools' broker settings."""
    client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id="writer")
    client.connect("127.0.0.1", broker.port)
    client.loop_start()
    try:
        for topic, payload in records():
            info = client.publish(topic, json.dumps(payload), qos=1, retain=True)
            info.wait_for_publish(WAIT_S)
            assert info.is_published(), topic
    finally:
        client.disconnect()
        client.loop_stop()
    path = tmp_path / "broker.yaml"
    path.write_text(yaml.safe_dump({"host": "127.0.0.1", "port": broker.port}))
    return ["--broker-config", str(path), "--timeout-s", str(WAIT_S)]


def test_every_retained_record_is_read_before_pending_decides(
    shop: list[str], capsys: pytest.CaptureFixture[str]
):
    """--pending: a row per machine with a desired record (138), up to date or pending: none missed."""
    code = main(["model", "rollout", "--pending", *shop, "--json"])
    report = json.loads(capsys.readouterr().out)
    rows = {row["machine_id"]: row for row in report["machines"]}
    expected = {name(k) for k in range(MACHINES) if k % 10 != 9} | set(UNBORN)
    assert set(rows) == expected, f"{len(rows)} of {len(expected)} machines seen"
    for k in range(MACHINES):
        if k % 10 == 9:
            continue
        row = rows[name(k)]
        if state(k) == "online":
            assert row["result"] == "up_to_date", row
        else:
            assert row["result"] == "pending" and row["presence"] == state(k), row
            reason = {
                6: "takes no models from the network (accept_models: false)",
                7: "run --pending again; an older compd",
            }.get(k % 10, "takes the desired model itself when it is back (accept_models)")
            assert reason in row["reason"], row
    assert {rows[m]["presence"] for m in UNBORN} == {"never seen"}
    assert code == 1, "machines still pending"


def test_online_names_every_machine_whose_birth_is_live(shop: list[str]):
    """--online's list: the 90 machines whose newest birth is newer than their death."""
    section, base_dir = broker_section(Path(shop[1]))
    found = online(section, base_dir, WAIT_S)
    assert found == [name(k) for k in range(MACHINES) if state(k) == "online"]


def test_fleet_list_shows_every_machine_as_json_and_as_a_table(
    shop: list[str], capsys: pytest.CaptureFixture[str]
):
    """compd fleet list: 153 rows, each with its host, model, state and last seen."""
    assert main(["fleet", "list", *shop, "--json"]) == 0
    rows = {row["machine_id"]: row for row in json.loads(capsys.readouterr().out)["machines"]}
    assert len(rows) == MACHINES + len(UNBORN)
    for k in range(MACHINES):
        row = rows[name(k)]
        assert row["host"] == f"host-{k}" and row["pid"] == 1000 + k, row
        assert row["model"] == "twin-z"
        words = state(k).split(" (")
        assert row["state"] == words[0] and row["reason"] == (
            words[1][:-1] if k % 5 in (1, 2) else None
        )
        assert row["runs_desired"] == (None if k % 10 == 9 else state(k) == "online"), row
        assert row["since_unix_s"] == BORN_UNIX_S + k
        if k % 5 == STOPPED:
            assert row["last_seen_unix_s"] == BORN_UNIX_S + k + 600, "the clean stop's time"
        elif k % 5 == LOST:
            assert row["last_seen_unix_s"] is None, (
                "a will says when it connected, not when it went"
            )
        else:
            assert row["last_seen_unix_s"] is not None
    for machine in UNBORN:
        assert rows[machine]["state"] == "never seen" and rows[machine]["host"] is None

    assert main(["fleet", "list", *shop]) == 0
    table = capsys.readouterr().out
    assert table.splitlines()[0].startswith(f"{MACHINES + len(UNBORN)} machines on 127.0.0.1:")
    assert f"{sum(state(k) == 'online' for k in range(MACHINES))} online" in table.splitlines()[0]
    line = next(line for line in table.splitlines() if f" {name(1)} " in line)
    words = line.replace("│", " ").split()
    assert words[:4] == [name(1), "host-1", "twin-z", OLD_SHA256[:12]], line
    assert "offline (stopped)" in line and "2026-09-21 14:23:21Z" in line, line
    line = next(line for line in table.splitlines() if f" {name(2)} " in line)
    assert "offline (connection lost)" in line and "after 2026-09-21 14:13:22Z" in line, line
    line = next(line for line in table.splitlines() if f" {name(0)} " in line)
    assert "online" in line and "runs it" in line and " now " in line, line


def test_a_user_the_broker_will_not_let_write_the_marker_is_told_so(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
):
    """An ACL without write on <prefix>/+/desired: an error naming the topic, never an empty list."""
    folder = tmp_path / "acl-broker"
    folder.mkdir()
    acl = folder / "acl"
    acl.write_text("topic read compd/#\n")
    broker = Mosquitto(folder, extra=[f"acl_file {acl}"]).start()
    try:
        path = tmp_path / "broker.yaml"
        path.write_text(yaml.safe_dump({"host": "127.0.0.1", "port": broker.port}))
        settings = ["--broker-config", str(path), "--timeout-s", "10"]
        assert main(["fleet", "list", *settings]) == EXIT_INPUT_ERROR
    finally:
        broker.stop()
    err = capsys.readouterr().err
    assert "refused this user's message" in err and "compd/+/desired" in err, err


def test_a_broker_that_drops_part_of_its_queue_is_an_error_not_a_smaller_fleet(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
):
    """max_queued_messages below the retained count: the marker is dropped with the rest; told so."""
    folder = tmp_path / "small-queue"
    folder.mkdir()
    broker = Mosquitto(folder, extra=["max_queued_messages 50"]).start()
    try:
        client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id="writer")
        client.connect("127.0.0.1", broker.port)
        client.loop_start()
        for k in range(200):
            birth = {"kind": "birth", "session": 1, "machine_id": name(k)}
            topic = f"compd/{name(k)}/birth"
            client.publish(topic, json.dumps(birth), qos=1, retain=True).wait_for_publish(WAIT_S)
        client.disconnect()
        client.loop_stop()
        path = tmp_path / "broker.yaml"
        path.write_text(yaml.safe_dump({"host": "127.0.0.1", "port": broker.port}))
        settings = ["--broker-config", str(path), "--timeout-s", "5"]
        assert main(["fleet", "list", *settings, "--json"]) == EXIT_INPUT_ERROR
    finally:
        broker.stop()
    captured = capsys.readouterr()
    assert not captured.out, "no list at all rather than a short one"
    assert "max_queued_messages" in captured.err, captured.err
