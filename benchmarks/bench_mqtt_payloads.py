"""Large MQTT messages: how long they stall the daemon's event loop (issue 41, item 7).

A daemon with ``accept_models: true`` takes ``cmd/model_load`` messages up to
1.4 MB (a 1 MB model file, base64) and, at connecting, the retained
``desired`` record of the same size. Each case publishes one message, through
a local mosquitto this script starts, to compd's own command side
(:class:`~compd.service.fleet.telemetry.Telemetry` with
:class:`~compd.service.fleet.remoteload.RemoteLoads`; the model load itself
answers at once: the model's checks are the control socket's, off the loop,
and not what is measured) while a ticker runs on the same event loop on
absolute deadlines every ``--period-s`` (the daemon's scheduler,
:func:`compd.service.loop.ticks.run_periodic`). Reported per case: the
message's size, the loop's longest stall (the ticker's worst lateness, ms),
the deadlines missed at the daemon's 1 s period (stall // 1 s) and the time
until the message was answered (s). Target: no deadline missed (stall < 1 s).

Cases: a JSON array of 500 kB and of 1.4 MB in a ``cmd/model_load`` request;
the same arrays in a retained ``desired`` record heard at connecting; a
genuine request carrying 1.4 MB of base64.

Run: ``PYTHONPATH=. python benchmarks/bench_mqtt_payloads.py [--period-s P]``.
Needs mosquitto (``.ci/install-system-packages``).
"""

from __future__ import annotations

import argparse
import asyncio
import base64
import contextlib
import json
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import paho.mqtt.client as mqtt
from common import environment, verdict
from paho.mqtt.enums import CallbackAPIVersion

from compd.service.fleet.mqttlink import Broker, Topics
from compd.service.fleet.remoteload import DESIRED_SCHEMA, MAX_PAYLOAD_BYTES, SCHEMA, RemoteLoads
from compd.service.fleet.telemetry import Telemetry
from compd.service.loop.clock import RealClock
from compd.service.loop.ticks import TickTiming, run_periodic
from tests.mosquitto import Mosquitto, Subscriber

#: The daemon's period: a stall longer than this misses a deadline.
DAEMON_PERIOD_S = 1.0
WAIT_S = 300.0


def array_request(size_bytes: int, **fields: Any) -> bytes:
    """A JSON object with ``fields`` and a ``junk`` array of ones, ``size_bytes`` long in all."""
    head = json.dumps(fields)[:-1] + ', "junk": ['
    count = max(1, (size_bytes - len(head) - 2) // 2)
    return (head + ",".join(["1"] * count) + "]}").encode()


def cases() -> list[tuple[str, str, bytes]]:
    """(name, topic kind, payload): the arrays on cmd/model_load and desired, and a real-sized model."""
    now = time.time()
    command = {"schema": SCHEMA, "request_id": "bench-1", "sent_unix_s": now}
    desired = {"schema": DESIRED_SCHEMA, "sha256": "0" * 64, "rollout_id": "bench"}
    blob = base64.b64encode(os.urandom((MAX_PAYLOAD_BYTES - 8192) * 3 // 4)).decode()
    model = command | {"request_id": "bench-b64", "model_base64": blob, "sha256": "0" * 64}
    out = []
    for size, label in ((500_000, "500 kB"), (1_400_000, "1.4 MB")):
        out.append((f"cmd/model_load array {label}", "cmd", array_request(size, **command)))
    for size, label in ((500_000, "500 kB"), (1_400_000, "1.4 MB")):
        out.append((f"desired (retained) array {label}", "desired", array_request(size, **desired)))
    out.append(("cmd/model_load base64 1.4 MB", "cmd", json.dumps(model).encode()))
    return out


async def one_case(port: int, kind: str, payload: bytes, period_s: float) -> tuple[float, float]:
    """Worst lateness of the ticker (s) and the time until handled (s) for one message."""
    answered = asyncio.Event()

    async def load(message: dict[str, Any]) -> dict[str, Any]:
        return {"model": "bench", "blend_s": 0.0}

    def reply(request_id: str, answer: dict[str, Any]) -> bool:
        answered.set()
        return True

    def event(e: Any) -> None:
        telemetry.event(e)
        if e.kind in ("model_refused", "fault"):
            answered.set()

    telemetry = Telemetry(Broker("127.0.0.1", port, f"bench-{kind}"), Topics("bench", "m"))
    remote = RemoteLoads(load, reply, event)
    telemetry.listen("model_load", remote.handle, max_bytes=MAX_PAYLOAD_BYTES)
    telemetry.take_desired(remote.take_desired)
    sender = mqtt.Client(CallbackAPIVersion.VERSION2, client_id="bench-sender")
    sender.connect("127.0.0.1", port)
    sender.loop_start()
    topic = "bench/m/cmd/model_load" if kind == "cmd" else "bench/m/desired"
    if kind == "desired":  # retained first: heard at connecting
        sender.publish(topic, payload, qos=1, retain=True).wait_for_publish(WAIT_S)
    stop = asyncio.Event()
    timing = TickTiming()

    async def noop(t: float) -> None:
        return None

    ticker = asyncio.ensure_future(
        run_periodic(RealClock(), period_s, noop, stop=stop, timing=timing)
    )
    started = time.monotonic()
    with Subscriber(port, "bench/m/birth") as births:
        telemetry.start()
        while kind == "cmd" and not births.of("birth"):  # born: subscribed to its commands before
            await asyncio.sleep(0.01)
    if kind == "cmd":
        await asyncio.to_thread(
            lambda: sender.publish(topic, payload, qos=1).wait_for_publish(WAIT_S)
        )
    with contextlib.suppress(TimeoutError):  # reported as the time waited
        await asyncio.wait_for(answered.wait(), WAIT_S)
    handled_s = time.monotonic() - started
    await asyncio.sleep(3 * period_s)  # a stall at the end shows in the ticker too
    stop.set()
    await ticker
    await telemetry.stop()
    # The retained birth, death and record cleared: the next case starts on an empty broker.
    for kind_topic in ("bench/m/birth", "bench/m/death", "bench/m/desired"):
        sender.publish(kind_topic, b"", qos=1, retain=True).wait_for_publish(WAIT_S)
    sender.loop_stop()
    sender.disconnect()
    return timing.max_lateness_s, handled_s


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--period-s", type=float, default=0.01, help="the ticker's period (s)")
    args = parser.parse_args()
    print(environment())
    worst_s = 0.0
    with tempfile.TemporaryDirectory() as folder:
        broker = Mosquitto(Path(folder)).start()
        try:
            print(f"{'case':36} {'bytes':>9} {'stall ms':>9} {'missed 1 s':>10} {'answered s':>10}")
            for name, kind, payload in cases():
                stall_s, handled_s = asyncio.run(
                    one_case(broker.port, kind, payload, args.period_s)
                )
                worst_s = max(worst_s, stall_s)
                missed = int(stall_s // DAEMON_PERIOD_S)
                print(
                    f"{name:36} {len(payload):9d} {stall_s * 1e3:9.1f} {missed:10d} {handled_s:10.2f}"
                )
        finally:
            broker.stop()
    passed = worst_s < DAEMON_PERIOD_S
    print(f"worst stall {worst_s * 1e3:.1f} ms; target: below the 1 s period: {verdict(passed)}")
    return 0 if passed else 1


if __name__ == "__main__":
    sys.exit(main())
