"""What ``compd read`` and ``compd probe`` read, and one read of it: points, rows, driver faults.

A :class:`LivePoint` is one address on one driver with the daemon's own
decoding (a signal's :class:`~compd.service.loop.points.SignalPoint`, an axis's
:class:`~compd.service.loop.offsets.AxisPoint`) and, for a signal, its
:class:`~compd.service.loop.signals.SignalMonitor`, so the verdict shown is the one
the daemon would reach on the same readings (range at once; spike, stuck and
stale as ``--watch`` goes on). :class:`LiveReader` reads every driver's points
as one batch through the driver's ``read_raw`` hook
(:func:`compd.drivers.base.read_raw`), each under the driver's timeout. A
driver that cannot be opened or read shows its error on each of its rows,
never a traceback, and is opened again on the next read; a batch refused as a
protocol error is read again address by address, so that one bad address
does not hide the others. What a person should check about a reading that
came is its row's ``hint``: how the address was read if written in another
numbering (a Modicon ``30001``, an ``input:30001`` that looks like one) and a
word order the address leaves open (both orders' values, or all 0).
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import cast

from compd.drivers.base import Driver, DriverType, RawReading, address_note, read_raw
from compd.errors import DriverError, DriverProtocolError
from compd.service.loop.signals import Health, SignalMonitor

#: Said when a serial line cannot be opened because another process holds it.
SERIAL_BUSY_HINT = (
    "a serial line has one master: if 'compd run' (or another poller) has this port open, "
    "stop it first (systemctl stop compd@NAME), or see the daemon's values with 'compd status'"
)


@dataclass(frozen=True)
class LivePoint:
    """One address to read, how its device value becomes the shown value, and its checks."""

    name: str
    kind: str  # signal, output, status, probe
    driver: str
    address: str
    unit: str = ""
    decode: Callable[[float], float] = float
    monitor: SignalMonitor | None = None


@dataclass(frozen=True)
class Row:
    """One point's reading: raw as the device gave it, the device value, the decoded value, the verdict."""

    point: LivePoint
    raw: str = ""
    device_value: float | None = None
    value: float | None = None
    health: str = "OK"
    problem: str = ""
    hint: str = ""  # what to check about a value that came (numbering, word order)

    @property
    def ok(self) -> bool:
        return self.health == "OK"

    def as_dict(self) -> dict[str, object]:
        p = self.point
        return {
            "name": p.name,
            "kind": p.kind,
            "driver": p.driver,
            "address": p.address,
            "raw": self.raw,
            "device_value": _finite(self.device_value),
            "value": _finite(self.value),
            "unit": p.unit,
            "health": self.health,
            "problem": self.problem,
            "hint": self.hint,
        }


@dataclass
class LiveDriver:
    """One driver as ``read``/``probe`` use it: opened on demand, reopened after a failure."""

    name: str
    driver: Driver
    timeout_s: float
    serial: bool = False  # on a serial line: a busy port gets :data:`SERIAL_BUSY_HINT`
    is_open: bool = False

    async def ensure_open(self) -> None:
        if not self.is_open:
            try:
                async with asyncio.timeout(self.timeout_s):
                    await self.driver.open()
            except Exception as exc:
                raise DriverError(self.explain(exc, "cannot connect")) from exc
            self.is_open = True

    async def read(self, addresses: Sequence[str]) -> dict[str, RawReading]:
        async with asyncio.timeout(self.timeout_s):
            readings: dict[str, RawReading] = await read_raw(self.driver, addresses)
        return readings

    async def write(self, address: str, value: float) -> None:
        await self.ensure_open()
        try:
            async with asyncio.timeout(self.timeout_s):
                await self.driver.write({address: value})
        except Exception as exc:
            raise DriverError(self.explain(exc, f"write to {address} failed")) from exc

    async def close(self) -> None:
        self.is_open = False
        try:
            async with asyncio.timeout(self.timeout_s):
                await self.driver.close()
        except Exception:
            pass  # close() never raises by contract; a hung close must not hang the command

    def explain(self, exc: BaseException, action: str) -> str:
        if isinstance(exc, TimeoutError):
            text = f"timed out after {self.timeout_s:g} s"
        elif isinstance(exc, DriverError | OSError):
            text = str(exc)
        else:  # a driver's defect (the loop treats it as a link fault too): say what it raised
            text = (
                f"{type(exc).__name__}: {exc} (the driver raised outside the DriverError contract)"
            )

        message = f"{action}: {text}"
        # pyserial names the lock ("could not exclusively lock port"); pymodbus only says
        # it cannot connect, so on a serial line every failed open gets the hint.
        if self.serial and action == "cannot connect":
            message += f" ({SERIAL_BUSY_HINT})"
        return message


@dataclass
class LiveReader:
    """Reads every point, batched per driver, drivers concurrently; keeps the monitors' history."""

    points: list[LivePoint]
    drivers: dict[str, LiveDriver]
    clock: Callable[[], float] = time.monotonic
    reads: int = field(default=0, init=False)
    #: The last read's rows (what Ctrl-C's exit status is judged on).
    last: list[Row] = field(default_factory=list, init=False)

    async def read(self) -> list[Row]:
        """One reading of every point, in the order given."""
        names = list(dict.fromkeys(p.driver for p in self.points))
        batches = await asyncio.gather(*(self._read_driver(name) for name in names))
        found = dict(zip(names, batches, strict=True))
        now_s = self.clock()
        self.reads += 1
        self.last = [
            replace(row, hint="; ".join(filter(None, (self._note(row.point), row.hint))))
            for row in (self._row(point, found[point.driver], now_s) for point in self.points)
        ]
        return self.last

    def _note(self, point: LivePoint) -> str:
        """How the point's driver type read its address, if in another numbering than written."""
        kind = cast("DriverType", type(self.drivers[point.driver].driver))  # built by its type
        return address_note(kind, point.address) or ""

    async def close(self) -> None:
        await asyncio.gather(*(d.close() for d in self.drivers.values()))

    async def _read_driver(self, name: str) -> dict[str, RawReading | str] | str:
        """The driver's raw readings (or an address's error) by address, or the error that stopped all."""
        live = self.drivers[name]
        addresses = list(dict.fromkeys(p.address for p in self.points if p.driver == name))
        try:
            await live.ensure_open()
        except DriverError as exc:
            return str(exc)
        try:
            try:
                return dict(await live.read(addresses))
            except DriverProtocolError:
                if len(addresses) == 1:
                    raise
            return await self._one_by_one(live, addresses)
        except Exception as exc:
            await live.close()
            return live.explain(exc, "read failed")

    @staticmethod
    async def _one_by_one(live: LiveDriver, addresses: list[str]) -> dict[str, RawReading | str]:
        """A refused batch read address by address: each refusal becomes that address's error."""
        readings: dict[str, RawReading | str] = {}
        for address in addresses:
            try:
                readings |= await live.read([address])
            except DriverProtocolError as exc:
                readings[address] = f"read failed: {exc}"
        return readings

    @staticmethod
    def _row(point: LivePoint, found: dict[str, RawReading | str] | str, now_s: float) -> Row:
        reading = found if isinstance(found, str) else found.get(point.address)
        if isinstance(reading, str):
            if point.monitor is not None:
                point.monitor.update(now_s, None)
            return Row(point, health="ERROR", problem=reading)
        device_value = None if reading is None else reading.value
        value = None if device_value is None else point.decode(device_value)
        raw = "" if reading is None else reading.raw
        note = "no value (none came in time)" if reading is None else reading.note
        hint = "" if reading is None else reading.hint
        if point.monitor is not None:
            verdict = point.monitor.update(now_s, value)
            if verdict.health is Health.OK:
                return Row(point, raw, device_value, value, hint=hint)
            problem = verdict.reason if value is not None or not note else note
            return Row(point, raw, device_value, value, verdict.health.name, problem, hint)
        if value is None:
            return Row(point, raw, health="NO VALUE", problem=note, hint=hint)
        return Row(point, raw, device_value, value, hint=hint)


def _finite(value: float | None) -> float | None:
    """JSON has no NaN: a non-finite number is null, as in every compd ``--json`` (``raw`` shows it)."""
    return value if value is not None and math.isfinite(value) else None
