"""Large, deep or oversize MQTT messages cost the 1 Hz tick nothing and are answered (issue 41, item 7).

Through a real mosquitto, with compd's own command side (Telemetry, RemoteLoads,
RemoteProbes) on the event loop beside the daemon's scheduler
(:func:`compd.service.loop.ticks.run_periodic` at the daemon's 1 s period):
the scheduler's deadline counters say whether a message stalled the loop.
"""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import paho.mqtt.client as mqtt
import pytest
from paho.mqtt.enums import CallbackAPIVersion

from compd.faultlog import Event
from compd.service.fleet.commands import MAX_HANDLING
from compd.service.fleet.mqttlink import Broker, Topics
from compd.service.fleet.remoteload import DESIRED_SCHEMA, MAX_PAYLOAD_BYTES, SCHEMA, RemoteLoads
from compd.service.fleet.remoteprobe import MAX_PAYLOAD_BYTES as MAX_PROBE_BYTES
from compd.service.fleet.remoteprobe import RemoteProbes
from compd.service.fleet.telemetry import Telemetry
from compd.service.fleet.wirecheck import MAX_DEPTH
from compd.service.loop.clock import RealClock
from compd.service.loop.ticks import TickTiming, run_periodic
from tests.mosquitto import WAIT_S, Mosquitto, Subscriber, mosquitto_binary

pytestmark = pytest.mark.skipif(
    mosquitto_binary() is None, reason="mosquitto is not installed: run .ci/install-system-packages"
)


def array_message(size_bytes: int, **fields: Any) -> bytes:
    """A JSON object with ``fields`` and a ``junk`` array of ones: ``size_bytes`` long in all."""
    head = json.dumps(fields)[:-1] + ', "junk": ['
    count = (size_bytes - len(head) - 2) // 2
    return (head + ",".join(["1"] * count) + "]}").encode()


class Machine:
    """A daemon's command side on a real broker, with the scheduler ticking beside it."""

    def __init__(self, port: int) -> None:
        self.port = port
        self.loads: list[dict[str, Any]] = []
        self.probes: list[dict[str, Any]] = []
        self.events: list[Event] = []
        self.timing = TickTiming()
        #: Set: probes are taken at once; clear: each waits (a daemon busy with them).
        self.release = asyncio.Event()

    async def load(self, message: dict[str, Any]) -> dict[str, Any]:
        self.loads.append(message)
        return {"model": "twin-z", "blend_s": 0.0}

    async def take(self, message: dict[str, Any]) -> dict[str, Any]:
        self.probes.append(message)
        await self.release.wait()
        return {"axis": message.get("axis")}

    async def run(
        self, act: Callable[[], None], done: Callable[[], bool], *, held: bool = False
    ) -> None:
        """Tick at 1 s; start the command side, ``act()`` once born, wait until ``done()``, tick once more.

        ``held``: probes wait until ``done()`` (the daemon busy with them), else they are taken at once.
        """
        if not held:
            self.release.set()
        telemetry = Telemetry(Broker("127.0.0.1", self.port, "compd-m"), Topics("compd", "m"))

        def event(e: Event) -> None:
            self.events.append(e)
            telemetry.event(e)

        loads = RemoteLoads(self.load, telemetry.reply, event)
        probes = RemoteProbes(self.take, telemetry.reply, event)
        telemetry.listen("model_load", loads.handle, max_bytes=MAX_PAYLOAD_BYTES)
        telemetry.listen("probe", probes.handle, max_bytes=MAX_PROBE_BYTES)
        telemetry.take_desired(loads.take_desired)
        stop = asyncio.Event()

        async def tick(t_s: float) -> None:
            return None

        ticker = asyncio.ensure_future(
            run_periodic(RealClock(), 1.0, tick, stop=stop, timing=self.timing)
        )
        telemetry.start()
        await until(lambda: telemetry.publishing, "publishing")
        act()
        await until(done, "answered")
        self.release.set()
        ticks = self.timing.ticks
        await until(lambda: self.timing.ticks > ticks + 1, "ticked after it")
        stop.set()
        await ticker
        await telemetry.stop()


async def until(predicate: Callable[[], bool], what: str) -> None:
    deadline = time.monotonic() + WAIT_S
    while not predicate():
        assert time.monotonic() < deadline, f"never {what}"
        await asyncio.sleep(0.01)


def sender(port: int) -> mqtt.Client:
    client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id="rollout")
    client.connect("127.0.0.1", port)
    client.loop_start()
    return client


def publish(client: mqtt.Client, kind: str, payload: bytes, *, retain: bool = False) -> None:
    client.publish(f"compd/m/{kind}", payload, qos=1, retain=retain).wait_for_publish(WAIT_S)


@pytest.mark.parametrize("size_bytes", [500_000, 1_400_000])
def test_a_large_command_costs_no_tick(tmp_path: Path, size_bytes: int):
    """A 500 kB or 1.4 MB JSON array on cmd/model_load is parsed and refused while every deadline is kept."""
    broker = Mosquitto(tmp_path).start()
    machine = Machine(broker.port)
    payload = array_message(size_bytes, request_id="big-1", schema=SCHEMA, sent_unix_s=time.time())
    assert len(payload) <= MAX_PAYLOAD_BYTES
    client = sender(broker.port)
    try:
        with Subscriber(broker.port, "compd/m/reply/#") as sub:
            asyncio.run(
                machine.run(
                    lambda: publish(client, "cmd/model_load", payload),
                    lambda: bool(sub.of("reply")),
                )
            )
    finally:
        client.loop_stop()
        broker.stop()
    (answer,) = sub.of("reply")
    assert answer["request_id"] == "big-1" and answer["result"] == "refused"
    assert machine.timing.ticks >= 2 and machine.timing.overruns == 0
    assert not machine.loads


def test_a_large_retained_desired_record_costs_no_tick(tmp_path: Path):
    """A 1.4 MB retained desired record, heard at connecting, is parsed and refused while every deadline is kept."""
    broker = Mosquitto(tmp_path).start()
    machine = Machine(broker.port)
    record = array_message(
        1_400_000, schema=DESIRED_SCHEMA, sha256="0" * 64, rollout_id="o1", model_base64=""
    )
    client = sender(broker.port)
    publish(client, "desired", record, retain=True)
    refused = lambda: any(e.kind == "model_refused" for e in machine.events)  # noqa: E731
    try:
        asyncio.run(machine.run(lambda: None, refused))
    finally:
        client.loop_stop()
        broker.stop()
    assert machine.timing.ticks >= 2 and machine.timing.overruns == 0
    assert not machine.loads


def test_an_oversize_or_too_deep_command_is_refused_unparsed_with_an_answer(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
):
    """A probe past its 4 kB bound and one nested past MAX_DEPTH are each answered refused, in one log line."""
    broker = Mosquitto(tmp_path).start()
    machine = Machine(broker.port)
    big = array_message(MAX_PROBE_BYTES + 100, request_id="p-big", axis="Z", measured_um=1.0)
    deep = (
        b'{"request_id": "p-deep", "a": ' + b"[" * (MAX_DEPTH + 1) + b"]" * (MAX_DEPTH + 1) + b"}"
    )
    client = sender(broker.port)

    def act() -> None:
        publish(client, "cmd/probe", big)
        publish(client, "cmd/probe", deep)

    try:
        with Subscriber(broker.port, "compd/m/reply/#") as sub:
            asyncio.run(machine.run(act, lambda: len(sub.of("reply")) == 2))
    finally:
        client.loop_stop()
        broker.stop()
    answers = {a["request_id"]: a for a in sub.of("reply")}
    assert answers["p-big"]["ok"] is False and "more than the 4096" in answers["p-big"]["reason"]
    assert (
        answers["p-deep"]["ok"] is False
        and f"more than {MAX_DEPTH} deep" in answers["p-deep"]["error"]
    )
    assert not machine.probes
    lines = [line for line in capsys.readouterr().out.splitlines() if "refused" in line]
    assert len(lines) == 2


def test_a_retained_command_is_refused_before_it_is_parsed(tmp_path: Path):
    """A retained cmd/model_load, not even JSON past its id, is answered refused as retained."""
    broker = Mosquitto(tmp_path).start()
    machine = Machine(broker.port)
    client = sender(broker.port)
    publish(
        client, "cmd/model_load", b'{"request_id": "old-1", "schema": [[[ not json', retain=True
    )
    try:
        with Subscriber(broker.port, "compd/m/reply/#") as sub:
            asyncio.run(machine.run(lambda: None, lambda: bool(sub.of("reply"))))
    finally:
        client.loop_stop()
        broker.stop()
    (answer,) = sub.of("reply")
    assert answer["request_id"] == "old-1" and "retained" in answer["reason"]


def test_the_same_bytes_again_are_a_replay_refused_before_a_parse():
    """A request's bytes taken once are refused the second time by their digest, never parsed again."""
    from tests.service.test_remoteload import ACCEPTED, Daemon, request

    daemon = Daemon(ACCEPTED)
    remote = RemoteLoads(
        daemon.load, lambda i, r: daemon.replies.append((i, r)), daemon.events.append
    )
    parsed: list[bytes] = []
    parse = remote.parser.parse

    async def counting(payload: bytes) -> Any:
        parsed.append(payload)
        return await parse(payload)

    remote.parser.parse = counting  # type: ignore[method-assign]
    payload = request()

    async def twice() -> None:
        await remote.handle(payload)
        await remote.handle(payload)

    asyncio.run(twice())
    assert len(daemon.loads) == 1 and len(parsed) == 1
    assert [r["result"] for _, r in daemon.replies] == ["accepted", "refused"]
    assert "a replay" in daemon.replies[1][1]["reason"]


def test_a_request_id_taken_before_is_refused_before_a_parse():
    """The same request_id in other bytes (sent again later) is refused as a replay from its bytes, unparsed."""
    from tests.service.test_remoteload import ACCEPTED, Daemon, request

    daemon = Daemon(ACCEPTED)
    remote = RemoteLoads(
        daemon.load, lambda i, r: daemon.replies.append((i, r)), daemon.events.append
    )
    parsed: list[bytes] = []
    parse = remote.parser.parse

    async def counting(payload: bytes) -> Any:
        parsed.append(payload)
        return await parse(payload)

    remote.parser.parse = counting  # type: ignore[method-assign]

    async def twice() -> None:
        await remote.handle(request(sent_unix_s=time.time()))
        await remote.handle(request(sent_unix_s=time.time() + 1, requested_by="again"))

    asyncio.run(twice())
    assert len(daemon.loads) == 1 and len(parsed) == 1
    assert daemon.replies[1][0] == "r1" and "a replay" in daemon.replies[1][1]["reason"]


def test_a_flood_of_commands_is_bounded_and_each_answered(tmp_path: Path):
    """20 probes at once while the daemon is busy: MAX_HANDLING are handled, the rest refused, all answered."""
    broker = Mosquitto(tmp_path).start()
    machine = Machine(broker.port)
    client = sender(broker.port)

    def act() -> None:
        for i in range(20):
            probe = {"request_id": f"p{i}", "axis": "Z", "measured_um": 1.0}
            publish(client, "cmd/probe", json.dumps(probe).encode())

    try:
        with Subscriber(broker.port, "compd/m/reply/#") as sub:
            asyncio.run(
                machine.run(act, lambda: len(sub.of("reply")) == 20 - MAX_HANDLING, held=True)
            )
            sub.wait_for(lambda s: len(s.of("reply")) == 20, "every probe answered")
    finally:
        client.loop_stop()
        broker.stop()
    refused = [a for a in sub.of("reply") if not a["ok"]]
    assert len(machine.probes) == MAX_HANDLING and len(refused) == 20 - MAX_HANDLING
    assert all("being handled already" in a["reason"] for a in refused)
