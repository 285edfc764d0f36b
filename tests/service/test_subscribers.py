"""The loop and its subscribers: one snapshot per tick, given to each; none of them can cost a tick."""

from __future__ import annotations

import asyncio
import time
from pathlib import Path

import pytest
from structlog.testing import capture_logs

from compd.errors import CompdError
from compd.service.daemon import Service
from compd.service.loop.clock import VirtualClock
from compd.service.loop.snapshot import TickSnapshot
from compd.service.loop.subscribers import Subscribers

from .daemon_setup import write_config


class Keeps:
    """A subscriber that keeps every snapshot it is given."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.seen: list[TickSnapshot] = []

    def on_tick(self, snapshot: TickSnapshot) -> None:
        self.seen.append(snapshot)


class FailsBetween(Keeps):
    """Raises on ticks ``first`` .. ``last`` (a consumer's bug: a full disk, a broken exporter)."""

    def __init__(self, name: str, first: int, last: int) -> None:
        super().__init__(name)
        self.first, self.last = first, last

    def on_tick(self, snapshot: TickSnapshot) -> None:
        super().on_tick(snapshot)
        if self.first <= snapshot.ticks <= self.last:
            raise RuntimeError("exporter broke")


def service_with(tmp_path: Path, *subscribers: Keeps) -> Service:
    service = Service(write_config(tmp_path), clock=VirtualClock(), control=False)
    for subscriber in subscribers:
        service.subscribers.add(subscriber)
    return service


def test_every_subscriber_is_given_the_same_snapshot_of_each_tick(tmp_path: Path) -> None:
    first, second = Keeps("first"), Keeps("second")
    service = service_with(tmp_path, first, second)
    asyncio.run(service.run(duration_s=9))
    assert [s.ticks for s in first.seen] == list(range(1, 11))
    assert all(a is b for a, b in zip(first.seen, second.seen, strict=True))
    last = first.seen[-1]
    assert last is service.last
    assert last.model is not None and last.model.name == service.compensator.active.compiled.name
    assert last.record.offsets_um == service.compensator.last.offsets_um


def test_the_snapshot_counters_are_the_ones_status_gives_and_cannot_be_changed(
    tmp_path: Path,
) -> None:
    seen = Keeps("seen")
    service = service_with(tmp_path, seen)
    asyncio.run(service.run(duration_s=4))
    counters = seen.seen[-1].counters
    assert counters["ticks"] == 5
    status = service.status()["counters"]
    assert {k: status[k] for k in counters} == dict(counters)
    with pytest.raises(TypeError):
        counters["ticks"] = 0  # type: ignore[index]


def test_a_failing_subscriber_is_one_fault_episode_and_costs_no_tick(tmp_path: Path) -> None:
    """It raises on ticks 3-6: one ERROR when it starts, one INFO when it works again; the others see all."""
    broken, other = FailsBetween("exporter", 3, 6), Keeps("other")
    service = service_with(tmp_path, broken, other)
    with capture_logs() as events:
        asyncio.run(service.run(duration_s=9))
    assert len(other.seen) == len(broken.seen) == 10
    assert service.compensator.counters.ticks == 10
    lines = [(e["log_level"], e["event"]) for e in events if e.get("subscriber") == "exporter"]
    assert lines.count(("error", "tick subscriber failed")) == 1
    assert lines.count(("info", "tick subscriber works again")) == 1
    assert service.subscribers.faults()["exporter"] == 1


def test_a_slow_subscriber_is_logged_as_slow_and_the_next_still_runs() -> None:
    """Taking more than its share of the period is a warning episode naming it, not a lost tick."""

    class Slow(Keeps):
        def on_tick(self, snapshot: TickSnapshot) -> None:
            super().on_tick(snapshot)
            time.sleep(0.05)

    subscribers = Subscribers(period_s=0.1)  # a share of 25 ms
    slow, after = Slow("slow"), Keeps("after")
    subscribers.add(slow)
    subscribers.add(after)
    snapshot = object.__new__(TickSnapshot)  # the registry does not look inside
    with capture_logs() as events:
        for _ in range(3):
            subscribers.publish(snapshot)
    assert len(after.seen) == 3
    slow_lines = [
        e for e in events if e.get("subscriber") == "slow" and e["log_level"] == "warning"
    ]
    assert [e["event"] for e in slow_lines] == ["tick subscriber slow"]  # one episode, one line
    assert slow_lines[0]["took_ms"] >= 50


def test_a_subscriber_name_is_registered_once() -> None:
    subscribers = Subscribers(period_s=1.0)
    subscribers.add(Keeps("recorder"))
    with pytest.raises(CompdError, match="recorder"):
        subscribers.add(Keeps("recorder"))


def test_the_builder_registers_what_the_config_asks_for_in_order(tmp_path: Path) -> None:
    """systemd's watchdog first, then the recorder, the state saver, telemetry and the page where configured."""
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    plain = Service(write_config(tmp_path / "a"), clock=VirtualClock(), control=False)
    assert [s.name for s in plain.subscribers] == ["systemd", "state"]
    config = write_config(
        tmp_path / "b", {"recorder": {"enabled": True}, "http": {"enabled": True, "port": 0}}
    )
    full = Service(config, clock=VirtualClock(), control=False)
    assert [s.name for s in full.subscribers] == ["systemd", "recorder", "state", "http"]


def test_subscribers_begin_in_order_and_one_that_cannot_ends_those_begun() -> None:
    """A page that cannot listen stops the start: the broker connection begun before it is ended."""
    said: list[str] = []

    class Lives(Keeps):
        def __init__(self, name: str, fails: bool = False) -> None:
            super().__init__(name)
            self.fails = fails

        async def begin(self) -> None:
            said.append(f"begin {self.name}")
            if self.fails:
                raise OSError("port in use")

        async def end(self, *, killed: bool) -> None:
            said.append(f"end {self.name}{' killed' if killed else ''}")

    subscribers = Subscribers(period_s=1.0)
    for subscriber in (Lives("broker"), Keeps("recorder"), Lives("page", fails=True)):
        subscribers.add(subscriber)
    with pytest.raises(OSError, match="port in use"):
        asyncio.run(subscribers.begin())
    assert said == ["begin broker", "begin page", "end broker"]
    said.clear()
    asyncio.run(subscribers.end(killed=True))
    assert said == ["end broker killed", "end page killed"]
