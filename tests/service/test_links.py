"""Driver supervision: failures never raise, reconnects back off exponentially, logging is ERROR once."""

from __future__ import annotations

import asyncio
from collections.abc import Mapping, Sequence

from structlog.testing import capture_logs

from compd.errors import DriverDisconnectedError
from compd.service.clock import VirtualClock
from compd.service.links import DriverLink


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
