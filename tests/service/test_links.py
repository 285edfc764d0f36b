"""Driver supervision: failures never raise, reconnects back off exponentially, logging is ERROR once."""

from __future__ import annotations

import asyncio
import itertools
from collections.abc import Mapping, Sequence

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from structlog.testing import capture_logs

from compd.drivers.base import Driver
from compd.errors import DriverDisconnectedError
from compd.service.daemon import Service
from compd.service.loop.clock import VirtualClock
from compd.service.loop.links import DriverLink

from .daemon_setup import write_config


class FlakyDriver:
    """A driver whose device is reachable only while ``up`` is true; it records open attempts."""

    def __init__(self, clock: VirtualClock) -> None:
        self.clock = clock
        self.up = True
        self.open_attempts: list[float] = []

    async def open(self) -> None:
        self.open_attempts.append(self.clock.now())
        if not self.up:
            raise DriverDisconnectedError("connection refused")

    async def read(self, points: Sequence[str]) -> dict[str, float]:
        if not self.up:
            raise DriverDisconnectedError("connection reset")
        return {p: 1.0 for p in points}

    async def write(self, values: Mapping[str, float]) -> None:
        if not self.up:
            raise DriverDisconnectedError("connection reset")

    async def close(self) -> None:
        return None


def test_backoff_doubles_and_recovery_is_logged_once():
    """While down, reconnects are tried after 1, 2, 4, 8 s (capped); ERROR once, DEBUG after, INFO on recovery."""
    clock = VirtualClock()
    driver = FlakyDriver(clock)
    link = DriverLink("plc", driver, clock, timeout_s=1.0, backoff_min_s=1.0, backoff_max_s=4.0)

    async def scenario() -> list[dict[str, float]]:
        await link.open()
        driver.up = False
        seen = []
        for t in range(40):
            clock.t = float(t)
            seen.append(await link.read(["a"]))
            await asyncio.sleep(0)  # let a background reconnect run
            if t == 30:
                driver.up = True
        return seen

    with capture_logs() as logs:
        seen = asyncio.run(scenario())
    assert seen[0] == {} and seen[-1] == {"a": 1.0}  # never raised
    assert driver.open_attempts[1:6] == [1.0, 3.0, 7.0, 11.0, 15.0]  # 1, 2, 4, then capped at 4 s
    levels = [(e["log_level"], e["event"]) for e in logs]
    assert [lvl for lvl, _ in levels].count("error") == 1
    assert levels[-1] == ("info", "driver reconnected")
    assert {lvl for lvl, _ in levels[1:-1]} <= {"error", "debug"} and link.reconnects == 1
    assert link.faults == 1


class WrongDriver:
    """A driver outside its contract: each call does what ``script`` says next (raise it, or return it)."""

    def __init__(self, script: list[object]) -> None:
        self.script = script
        self.calls = 0

    async def _next(self) -> object:
        outcome = self.script[self.calls % len(self.script)]
        self.calls += 1
        if isinstance(outcome, BaseException):
            raise outcome
        return outcome

    async def open(self) -> None:
        await self._next()

    async def read(self, points: Sequence[str]) -> dict[str, float]:
        return await self._next()  # type: ignore[return-value]

    async def write(self, values: Mapping[str, float]) -> None:
        await self._next()

    async def close(self) -> None:
        await self._next()


_unexpected = st.sampled_from(
    [TypeError("x"), KeyError("ok"), AttributeError("items"), ValueError("abc"), RecursionError()]
)
_wrong_values = st.one_of(
    st.none(),
    st.integers(),
    st.text(max_size=5),
    st.lists(st.floats(), max_size=3),
    st.dictionaries(
        st.sampled_from(["a", "b", "unasked"]),
        st.none() | st.text(max_size=3) | st.integers() | st.floats() | st.lists(st.integers()),
        max_size=3,
    ),
)


@settings(max_examples=40, deadline=None)
@given(script=st.lists(_unexpected | _wrong_values, min_size=1, max_size=6))
def test_a_driver_outside_its_contract_is_a_fault_never_an_exception(script):
    """Whatever a driver raises (an Exception) or returns, the link never raises; reads give floats for asked points."""
    clock = VirtualClock()
    link = DriverLink("plc", WrongDriver(script), clock, timeout_s=1.0)

    async def scenario() -> None:
        await link.open()
        for t in range(12):
            clock.t = float(t)
            values = await link.read(["a", "b"])
            assert set(values) <= {"a", "b"}
            assert all(type(v) is float for v in values.values())
            assert await link.write({"a": 1.0}) in (True, False)
            await asyncio.sleep(0)  # let a background reconnect run
        await link.close()

    with capture_logs() as logs:
        asyncio.run(scenario())
    bugs = [e for e in logs if "not a DriverError" in e["event"]]
    assert len(bugs) == len({type(e["exc_info"]) for e in bugs})  # each type once


def test_an_unexpected_exception_goes_down_and_reconnects_with_backoff():
    """A TypeError from read downs the link like a DriverError: reopened after the backoff; one traceback, one count."""
    clock = VirtualClock()
    driver = WrongDriver([None, TypeError("list indices must be integers"), None])
    link = DriverLink("plc", driver, clock, timeout_s=1.0, backoff_min_s=2.0)

    async def scenario() -> list[dict[str, float]]:
        await link.open()  # call 0: fine
        seen = [await link.read(["a"])]  # call 1: TypeError, the link goes down
        assert not link.up and link.next_attempt_s == 2.0
        for t in (1.0, 2.0):
            clock.t = t
            seen.append(await link.read(["a"]))
            await asyncio.sleep(0)
        return seen

    with capture_logs() as logs:
        seen = asyncio.run(scenario())
    assert seen == [{}, {}, {}] and driver.calls == 3 and link.up  # reopened (call 2) at t = 2 s
    assert link.unexpected == 1  # counted, for the fault soak's judge
    errors = [e for e in logs if e["log_level"] == "error"]
    assert [e["event"] for e in errors] == [
        "driver read raised TypeError, not a DriverError: a bug in the driver; the link treats it "
        "as a fault and reconnects",
        "driver read failed",
    ]


@pytest.mark.parametrize("stop", [asyncio.CancelledError, KeyboardInterrupt])
def test_cancellation_and_interrupts_pass_through(stop):
    """CancelledError and KeyboardInterrupt from a driver are not faults: they leave the link's call."""
    link = DriverLink("plc", WrongDriver([None, stop()]), VirtualClock(), timeout_s=1.0)

    async def scenario() -> None:
        await link.open()
        await link.read(["a"])

    with pytest.raises(stop):
        asyncio.run(scenario())


class Sabotaged:
    """A real driver whose every third read and write raises a bug's exception instead."""

    def __init__(self, driver: Driver) -> None:
        self.driver = driver
        self.calls = 0
        self.bugs = itertools.cycle([TypeError("bad shape"), KeyError("ok"), RecursionError()])

    def _bug(self) -> None:
        self.calls += 1
        if self.calls % 3 == 0:
            raise next(self.bugs)

    async def open(self) -> None:
        await self.driver.open()

    async def read(self, points: Sequence[str]) -> dict[str, float]:
        self._bug()
        return await self.driver.read(points)

    async def write(self, values: Mapping[str, float]) -> None:
        self._bug()
        await self.driver.write(values)

    async def close(self) -> None:
        await self.driver.close()


def test_the_daemon_runs_on_through_a_driver_that_raises_anything(tmp_path):
    """A daemon whose driver raises TypeError, KeyError and RecursionError runs its whole span, reconnecting."""
    service = Service(write_config(tmp_path), clock=VirtualClock(), control=False)
    link = service.links["machine"]
    link.driver = Sabotaged(link.driver)
    with capture_logs() as logs:
        asyncio.run(service.run(duration_s=120.0))
    assert service.compensator.counters.ticks >= 100
    assert link.faults >= 10 and link.reconnects >= 10
    bugs = [e for e in logs if "not a DriverError" in e["event"]]
    assert sorted(type(e["exc_info"]).__name__ for e in bugs) == [
        "KeyError",
        "RecursionError",
        "TypeError",
    ]


class Waiting:
    """A driver that does its first step at once and then waits ``wait_s`` (real s) for its device."""

    def __init__(self, wait_s: float) -> None:
        self.wait_s = wait_s
        self.steps: list[str] = []

    async def open(self) -> None:
        return None

    async def read(self, points: Sequence[str]) -> dict[str, float]:
        self.steps.append("asked")
        await asyncio.sleep(0)  # the request goes out
        await asyncio.sleep(self.wait_s)  # the answer comes back
        self.steps.append("answered")
        return {p: 2.0 for p in points}

    async def write(self, values: Mapping[str, float]) -> None:
        self.steps.append("asked")
        await asyncio.sleep(self.wait_s)
        self.steps.append("answered")

    async def close(self) -> None:
        return None


def test_a_driver_that_waits_for_its_device_is_read_and_written_through_its_waits():
    """A read or write that waits (on the event loop) is resumed until it answers, its value returned."""
    driver = Waiting(0.001)
    link = DriverLink("plc", driver, VirtualClock(), timeout_s=5.0)

    async def scenario() -> tuple[dict[str, float], bool]:
        await link.open()
        return await link.read(["a", "b"]), await link.write({"c": 1.0})

    assert asyncio.run(scenario()) == ({"a": 2.0, "b": 2.0}, True)
    assert driver.steps == ["asked", "answered", "asked", "answered"] and link.state == "up"


@pytest.mark.parametrize("action", ["read", "write"])
def test_a_driver_that_waits_past_the_timeout_is_a_timed_out_fault(action):
    """A call that started at once but waits longer than ``timeout_s`` is cut there: down, 'timed out'."""
    driver = Waiting(3600.0)
    link = DriverLink("plc", driver, VirtualClock(), timeout_s=0.02)

    async def scenario() -> object:
        await link.open()
        return await (link.read(["a"]) if action == "read" else link.write({"a": 1.0}))

    assert asyncio.run(scenario()) in ({}, False)
    assert driver.steps == ["asked"]  # cancelled in its wait, never answered
    assert link.state == "not connected" and link.last_error == "timed out"


def test_cancelling_the_loop_cancels_a_driver_call_that_waits():
    """Cancelling the task cancels the driver's wait inside the call; the CancelledError passes through."""
    driver = Waiting(3600.0)
    link = DriverLink("plc", driver, VirtualClock(), timeout_s=3600.0)

    async def scenario() -> None:
        await link.open()
        task = asyncio.ensure_future(link.read(["a"]))
        await asyncio.sleep(0.01)
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        assert link.state == "not connected" and link.failures == 0  # not a fault

    asyncio.run(scenario())
    assert driver.steps == ["asked"]
