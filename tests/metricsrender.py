"""One real ``/metrics`` render of compd on the simulated machine, with MQTT telemetry, the recorder and http on.

The metrics tests and the deploy tests (alert rules, the Grafana dashboard)
read the same exposition, so a name the rules or the dashboard use must be
one compd really exports.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml
from prometheus_client.parser import text_string_to_metric_families

from compd.service.daemon import Service
from compd.service.loop.compensator import TickRecord
from compd.service.loop.probemessages import ProbeRequest
from compd.sim.plc.machine import SimulatedMachine
from compd.sim.plc.run import run_simulation
from tests.mosquitto import WAIT_S, Mosquitto, machine_config

MACHINE_ID = "mill-prom"
#: The tick at which the metrics are rendered.
RENDER_AT = 60


@dataclass
class Render:
    """The exposition text, ``compd status``'s snapshot at the same tick, and the samples parsed."""

    text: str
    status: dict[str, Any]
    types: dict[str, str]
    samples: dict[str, dict[tuple[tuple[str, str], ...], float]]

    @property
    def families(self) -> set[str]:
        """Every metric family name, as PromQL may name it (``_total``, ``_bucket`` ... included)."""
        return set(self.types) | set(self.samples)


def render_metrics(directory: Path, broker_port: int) -> Render:
    """Run the simulated machine for :data:`RENDER_AT` ticks and render ``/metrics`` at the last."""
    telemetry = {
        "machine_id": MACHINE_ID,
        "host": "127.0.0.1",
        "port": broker_port,
        "every_ticks": 1,
    }
    config = machine_config(directory, telemetry=telemetry)
    doc = yaml.safe_load(config.path.read_text())
    doc["machine_id"] = MACHINE_ID
    doc["http"] = {"port": 0}
    doc["recorder"] = {"enabled": True, "directory": str(directory / "records")}
    doc["probes"] = {"axes": {"Z": None}}  # a probe taken below: its series are in the render
    config.path.write_text(yaml.safe_dump(doc, sort_keys=False))
    from compd.service.config.loading import load_config

    config = load_config(config.path)
    seen: dict[str, Any] = {}

    def at_tick(service: Service, machine: SimulatedMachine, record: TickRecord) -> None:
        ticks = service.compensator.counters.ticks
        if ticks == 2:  # virtual time waits for the broker, which runs in real time
            deadline = time.monotonic() + WAIT_S
            while not (service.telemetry is not None and service.telemetry.counters.connected):
                assert time.monotonic() < deadline, "compd never connected to the broker"
                time.sleep(0.005)
        if ticks == RENDER_AT - 2 and service.probing is not None:
            service.probing.offer(ProbeRequest("Z", 0.4, record.wall_unix_s, "test", "residue"))
        if ticks == RENDER_AT and service.http is not None:
            seen["text"] = service.http.metrics.render()[0].decode()
            seen["status"] = service.status()

    asyncio.run(run_simulation(config, duration_s=RENDER_AT + 2, on_tick=at_tick))
    types: dict[str, str] = {}
    samples: dict[str, dict[tuple[tuple[str, str], ...], float]] = {}
    for family in text_string_to_metric_families(seen["text"]):
        types[family.name] = family.type
        for sample in family.samples:
            samples.setdefault(sample.name, {})[tuple(sorted(sample.labels.items()))] = sample.value
    return Render(seen["text"], seen["status"], types, samples)


@contextmanager
def rendered_with_broker(folder: Path) -> Iterator[Render]:
    """:func:`render_metrics` of a run publishing to a mosquitto of its own under ``folder``."""
    (folder / "broker").mkdir()
    broker = Mosquitto(folder / "broker").start()
    try:
        yield render_metrics(folder / "run", broker.port)
    finally:
        broker.stop()
