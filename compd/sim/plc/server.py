"""What every simulated PLC server offers the simulated machine: start, stop, publish, report writes.

A server is built from the settings of one driver instance of a compd config
(the very settings compd's driver connects with) and the addresses compd
reads (``inputs``) and writes (``outputs``) through that instance. It serves
the raw values the machine publishes at those addresses, encoded exactly as
the driver decodes them (address syntax, type, byte and word order), and
calls ``on_write(address, raw_value)`` for every value compd writes, decoded
the way the driver encoded it. Values are *raw*: the config's
``scale``/``offset`` (signals) and ``encoding`` (outputs) are applied by the
machine, not by the server.

``stop`` then ``start`` again is a PLC restart: clients see the connection
drop and must reconnect; published values survive it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, Protocol

from compd.drivers.points import INT_RANGES, PointCodec

#: Called by a server for each value compd wrote: ``(address, raw_value)``.
WriteSink = Callable[[str, float], None]


class PlcServer(Protocol):
    """One simulated controller endpoint (a Modbus TCP server, an OPC UA server, ...)."""

    async def start(self) -> None:
        """Listen (bind, create nodes, open the pty or bus); raise ``OSError``/``RuntimeError`` with a clear text."""

    async def stop(self) -> None:
        """Stop listening and drop every client connection; never raises."""

    def publish(self, values: Mapping[str, float]) -> None:
        """Set the raw values served at these input addresses (from now on; cheap, called every step)."""


class PlcServerType(Protocol):
    """A server class: built from one driver instance's validated settings."""

    def __call__(
        self,
        settings: Any,
        *,
        inputs: Sequence[str],
        outputs: Sequence[str],
        on_write: WriteSink,
        base_dir: Path,
    ) -> PlcServer: ...


def servable(codec: PointCodec, raw: float) -> float:
    """What a sensor behind ``codec`` reads for ``raw``: saturated at its type's range, never an error.

    A PLC's analogue input saturates rather than wrapping, and a broken sensor
    (NaN) reads as the type's minimum (the usual wire-break code) on an
    integer point; a float point carries NaN as it is.
    """
    if codec.type in ("float32", "float64"):
        return raw
    low, high = INT_RANGES[codec.type]
    if math.isnan(raw):
        return float(low * codec.scale + codec.offset)
    counts = min(max((raw - codec.offset) / codec.scale, low), high)
    return float(round(counts) * codec.scale + codec.offset)
