"""MQTT payloads a consumer can trust, against a real mosquitto: paired events, clean numbers, units said.

A dashboard pairs each ``fault`` with its ``cleared``, compares a status's
health and values with the Prometheus metrics, and shows numbers as sent.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest

from compd.service.daemon import Service
from compd.service.loop.compensator import TickRecord
from compd.sim.plc.machine import SimulatedMachine
from tests.mosquitto import Mosquitto, Subscriber, machine_config, mosquitto_binary
from tests.service.test_telemetry import simulate, wait_until

pytestmark = pytest.mark.skipif(
    mosquitto_binary() is None,
    reason="mosquitto is not installed: run .ci/install-system-packages",
)


def _run(broker: Mosquitto, tmp_path: Path, faults: list[dict[str, Any]]) -> Subscriber:
    """300 s of the simulated machine with ``faults``, every status heard; the subscriber afterwards."""
    telemetry = {"machine_id": "mill-e", "host": "127.0.0.1", "port": broker.port}
    simulation = {"scenario": "production", "hours": 1, "seed": 3, "faults": faults}
    config = machine_config(tmp_path / "run", telemetry=telemetry, simulation=simulation)

    def connected(service: Service, machine: SimulatedMachine, record: TickRecord) -> None:
        if service.compensator.counters.ticks == 2:
            t = service.telemetry
            assert t is not None
            wait_until(lambda: t.publishing)  # what is queued meanwhile is published after

    with Subscriber(broker.port, "compd/#") as sub:
        simulate(config, 300, on_tick=connected)
        sub.wait_for(lambda s: s.of("death", "mill-e"), "the death")
    return sub


HEALTH_CODES = {"ok": 0, "held": 1, "faulted": 2, "estimated": 3}


def _episode(event: dict[str, Any]) -> tuple[str, str]:
    details = event["details"]
    return ("signal", details["signal"]) if "signal" in details else ("driver", details["driver"])


def test_every_cleared_follows_its_fault_and_a_driver_episode_ends_with_cleared(
    broker: Mosquitto, tmp_path: Path
):
    """No ``cleared`` at start; each ends an episode its ``fault`` began; a driver's is cleared, then reconnected."""
    faults = [
        # On a model input with no second sensor: its prediction from the others stands in.
        {"kind": "nan", "signal": "T_headstock_degC", "at_s": 60, "duration_s": 60},
        {"kind": "drop", "driver": "plc", "at_s": 200, "duration_s": 10},
    ]
    sub = _run(broker, tmp_path, faults)
    events = [e for e in sub.of("event", "mill-e") if e["event"] in ("fault", "cleared")]
    events = [e for e in events if "signal" in e["details"] or "driver" in e["details"]]
    open_episodes: set[tuple[str, str]] = set()
    for event in events:
        episode = _episode(event)
        if event["event"] == "fault":
            open_episodes.add(episode)
        else:
            assert episode in open_episodes, f"cleared without its fault: {event}"
            open_episodes.discard(episode)
    assert not open_episodes, "every episode ended"
    kinds = [(e["event"], e["message"]) for e in sub.of("event", "mill-e")]
    # The NaN on a model input: replaced by its prediction from the other sensors, then trusted again.
    assert ("cleared", "signal agrees with the other sensors again: its readings are used") in kinds
    cleared = kinds.index(("cleared", "driver reconnected"))
    assert kinds[cleared + 1] == ("reconnected", "driver reconnected")


def _floats(value: Any) -> list[float]:
    if isinstance(value, float):
        return [value]
    if isinstance(value, dict):
        return [f for v in value.values() for f in _floats(v)]
    if isinstance(value, list):
        return [f for v in value for f in _floats(v)]
    return []


def test_payload_numbers_are_clean_and_their_units_and_health_codes_are_said(
    broker: Mosquitto, tmp_path: Path
):
    """No -0.0; inputs at their register's resolution (0.01) exactly; the birth says units and metric names."""
    sub = _run(broker, tmp_path, [])
    statuses = sub.of("status", "mill-e")
    assert statuses
    for status in statuses:
        assert not [f for f in _floats(status) if f == 0.0 and math.copysign(1.0, f) < 0], status
        for name, reading in status["inputs"].items():
            value = reading["value"]
            assert repr(value) == repr(round(value, 2)), f"{name}: {value!r}"
            assert reading["health_code"] == HEALTH_CODES[reading["health"]]
    birth = sub.of("birth", "mill-e")[0]
    assert birth["units"]["offsets"] == "um" and birth["units"]["model_outputs"] == "um"
    assert birth["health_codes"] == HEALTH_CODES
    spindle = birth["signals"]["T_spindle_degC"]
    assert spindle["unit"] == "degC"
    assert spindle["metric"] == {"name": "compd_signal_celsius", "factor": 1.0}
