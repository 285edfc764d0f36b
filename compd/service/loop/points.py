"""The I/O points of a tick: where signals are read and the status word written, batched per driver.

A tick reads every signal (and every offset read back) in one batch per
driver, all drivers concurrently, and writes the offsets, the status word
and the heartbeat the same way. Every call goes through a
:class:`~compd.service.loop.links.DriverLink`, so none raises: a failed read gives
no values, a failed write ``False`` for its driver.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Coroutine, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, TypeVar

from compd.service.loop.links import DriverLink
from compd.service.loop.offsets import AxisPoint

T = TypeVar("T")


@dataclass(frozen=True)
class SignalPoint:
    """Where a signal is read: ``value = convert(raw) * scale + offset``.

    ``kind`` converts the raw reading first: ``int`` rounds it (a register
    count), ``bool`` makes it 1.0 when non-zero, else 0.0.
    """

    name: str
    driver: str
    address: str
    scale: float = 1.0
    offset: float = 0.0
    kind: str = "float"
    #: ``1 / scale`` when whole (see :func:`_divisor`), worked out once, not every tick.
    divisor: float | None = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "divisor", _divisor(self.scale))

    def convert(self, raw: float) -> float:
        if self.kind != "float" and math.isfinite(raw):
            raw = float(round(raw)) if self.kind == "int" else float(raw != 0)
        divisor = self.divisor
        scaled = raw / divisor if divisor is not None else raw * self.scale
        return scaled + self.offset + 0.0  # + 0.0: never -0.0


def _divisor(scale: float) -> float | None:
    """``1 / scale`` where it is a whole number (0.01 -> 100.0), else None.

    A register of 2115 at scale 0.01 is 21.15: ``2115 / 100`` is the double
    nearest to it, ``2115 * 0.01`` is 21.150000000000002 (0.01 has no exact
    double), and the noise would reach every recording and payload.
    """
    if scale == 0.0 or abs(scale) >= 1.0:
        return None
    inverse = 1.0 / scale
    whole = round(inverse)
    return float(whole) if abs(inverse - whole) <= 1e-9 * abs(inverse) else None


@dataclass(frozen=True)
class StatusPoint:
    driver: str
    status_address: str
    heartbeat_address: str
    #: Whether the status point holds the readback-mismatch bit (:mod:`compd.service.loop.safety`).
    mismatch_bit: bool = True
    #: Whether the status point holds the model-fault bit (:mod:`compd.service.loop.safety`).
    model_fault_bit: bool = True


class DriverBatches:
    """The points each driver serves, read and written as one batch per driver."""

    def __init__(
        self,
        signals: Sequence[SignalPoint],
        axes: Sequence[AxisPoint],
        status: StatusPoint | None,
        links: Mapping[str, DriverLink],
        also_read: Sequence[SignalPoint] = (),
    ) -> None:
        """``also_read``: points read with the signals but not checked as signals (a probe's registers)."""
        self.axes = list(axes)
        self.status = status
        self.links = links
        self._reads: dict[str, list[SignalPoint]] = {}
        for point in (*signals, *also_read):
            self._reads.setdefault(point.driver, []).append(point)
        self._readbacks: dict[str, list[AxisPoint]] = {}
        for axis in self.axes:
            if axis.readback:
                self._readbacks.setdefault(axis.driver, []).append(axis)
                self._reads.setdefault(axis.driver, [])
        #: Per driver, the addresses read each tick: its signals, then its offsets read back.
        self._addresses = {
            d: [p.address for p in points] + [a.address for a in self._readbacks.get(d, [])]
            for d, points in self._reads.items()
        }
        self._drivers = list(self._reads)

    async def read(self) -> tuple[dict[str, float], dict[str, float]]:
        """Signal values by name, and the raw offsets read back by axis name.

        An offset read back is passed on whatever it is, NaN and inf included
        (the link has made every value a float, :mod:`compd.service.loop.links`):
        what the PLC holds is judged by :class:`~compd.service.loop.offsets.HeldOffsets`,
        which takes such a value as a fault, never as "not read" (which would
        leave it in place unflagged).
        """
        drivers = self._drivers
        if len(drivers) == 1:  # the usual case: no list of calls, no gather
            results = [await self.links[drivers[0]].read(self._addresses[drivers[0]])]
        else:
            results = await _all([self.links[d].read(self._addresses[d]) for d in drivers])
        values: dict[str, float] = {}
        held: dict[str, float] = {}
        for driver, raw in zip(drivers, results, strict=True):
            for point in self._reads[driver]:
                if point.address in raw:
                    values[point.name] = point.convert(raw[point.address])
            for axis in self._readbacks.get(driver, ()):
                if axis.address in raw:
                    held[axis.name] = raw[axis.address]
        return values, held

    async def write(
        self,
        raws: Mapping[str, float],
        word: int,
        heartbeat: int,
        also: Mapping[str, Mapping[str, float]] | None = None,
    ) -> dict[str, bool]:
        """Write the raw offsets (by axis), the status word and the heartbeat; success per driver.

        ``also``: more raw values per driver and address, in the same batch (a probe's echo).
        """
        batches: dict[str, dict[str, float]] = {}
        if also:
            batches = {d: dict(b) for d, b in also.items()}
        for axis in self.axes:
            if axis.name in raws:
                batches.setdefault(axis.driver, {})[axis.address] = raws[axis.name]
        if self.status is not None:
            batch = batches.setdefault(self.status.driver, {})
            batch[self.status.status_address] = float(word)
            batch[self.status.heartbeat_address] = float(heartbeat)
        if len(batches) == 1:  # the usual case: no list of calls, no gather
            ((driver, batch),) = batches.items()
            return {driver: await self.links[driver].write(batch)}
        drivers = list(batches)
        results = await _all([self.links[d].write(batches[d]) for d in drivers])
        return dict(zip(drivers, results, strict=True))

    async def write_status(self, word: int, heartbeat: int) -> bool:
        """Write the status word and the heartbeat alone (the last word at shutdown)."""
        point = self.status
        if point is None:
            return False
        batch = {point.status_address: float(word), point.heartbeat_address: float(heartbeat)}
        return await self.links[point.driver].write(batch)


async def _all(calls: list[Coroutine[Any, Any, T]]) -> list[T]:
    """``asyncio.gather``, without its task per call when there is only one (the usual case)."""
    if len(calls) == 1:
        return [await calls[0]]
    return list(await asyncio.gather(*calls))
