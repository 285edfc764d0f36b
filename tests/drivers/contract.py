"""The contract every driver passes: one suite, run against every backend.

A driver's test module subclasses :class:`DriverContract` and provides the
``setup`` fixture: a fresh driver (not yet open), addresses it can read, one
it can write, one that does not exist, and a ``break_connection()`` callable
that makes the device unreachable (a stopped server, a dropped link). Each
test closes the driver it opened, on the event loop it opened it on.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import pytest

from compd.drivers.base import Driver, RawReading, read_raw
from compd.errors import DriverDisconnectedError, DriverError, DriverTimeoutError


@dataclass
class ContractSetup:
    driver: Driver
    readable: Sequence[str]
    writable: str
    missing: str
    break_connection: Callable[[], None]


def run_calls(driver: Driver, *calls: tuple[str, Any]) -> list[Any]:
    """Open ``driver``, await each ``(method, argument)`` call in turn, close; return the results."""

    async def scenario() -> list[Any]:
        await driver.open()
        try:
            return [await getattr(driver, name)(arg) for name, arg in calls]
        finally:
            await driver.close()

    return asyncio.run(scenario())


class DriverContract:
    """Subclass and define a ``setup`` fixture returning :class:`ContractSetup`."""

    def test_is_a_driver(self, setup: ContractSetup) -> None:
        """The driver satisfies the Driver protocol."""
        assert isinstance(setup.driver, Driver)

    def test_reads_floats_for_the_requested_addresses(self, setup: ContractSetup) -> None:
        """After open, a read returns a float for each requested address and nothing else."""

        (values,) = run_calls(setup.driver, ("read", list(setup.readable)))
        assert set(values) <= set(setup.readable) and values
        assert all(isinstance(v, float) and math.isfinite(v) for v in values.values())

    def test_raw_readings_give_the_values_read_gives(self, setup: ContractSetup) -> None:
        """``read_raw`` (the hook, or its fallback) shows a raw text and read()'s value for each address."""

        async def scenario() -> tuple[dict[str, float], dict[str, RawReading]]:
            await setup.driver.open()
            try:
                return await setup.driver.read(readable), await read_raw(setup.driver, readable)
            finally:
                await setup.driver.close()

        readable = list(setup.readable)
        values, raws = asyncio.run(scenario())
        assert set(raws) <= set(readable) and raws
        assert all(r.raw for r in raws.values())
        assert {a: r.value for a, r in raws.items() if a in values} == {
            a: v for a, v in values.items() if a in raws
        }

    def test_write_is_accepted(self, setup: ContractSetup) -> None:
        """After open, writing a value to a writable address succeeds."""

        run_calls(setup.driver, ("write", {setup.writable: 1.25}))

    def test_unknown_address_is_a_driver_error(self, setup: ContractSetup) -> None:
        """Reading an address the device does not have raises a DriverError, not the library's exception."""

        with pytest.raises(DriverError):
            run_calls(setup.driver, ("read", [setup.missing]))

    def test_lost_connection_is_disconnected_or_timeout(self, setup: ContractSetup) -> None:
        """When the device is unreachable, read and write raise DriverDisconnectedError or DriverTimeoutError."""

        async def scenario() -> list[BaseException]:
            await setup.driver.open()
            setup.break_connection()
            raised = []
            for call in (
                setup.driver.read(list(setup.readable)),
                setup.driver.write({setup.writable: 0.0}),
            ):
                try:
                    await asyncio.wait_for(call, 10.0)
                except BaseException as exc:
                    raised.append(exc)
            await setup.driver.close()
            return raised

        raised = asyncio.run(scenario())
        assert len(raised) == 2
        assert all(isinstance(e, DriverDisconnectedError | DriverTimeoutError) for e in raised)

    def test_close_never_raises(self, setup: ContractSetup) -> None:
        """close() after open, and a second close(), never raise."""

        async def scenario() -> None:
            await setup.driver.open()
            await setup.driver.close()
            await setup.driver.close()

        asyncio.run(scenario())
