"""Profibus DP through a gateway: the DP process image read and written over Modbus TCP or CAN.

compd does not speak Profibus itself: a DP gateway (a slave on the PLC's
Profibus) copies the DP input area to its other side and that side's data
into the DP output area. Two kinds of other side are supported
(``transport``):

``modbus_tcp``
    e.g. an Anybus Communicator: the input area as input registers from
    ``input_register`` on, the output area as holding registers from
    ``output_register`` on (two bytes a register, first byte high). One
    request reads the whole input area per tick and one request writes the
    whole output area, so every value of a tick comes from one gateway cycle
    and the PLC sees one consistent output image. Reading an ``out:``
    address reads the output area back from the gateway.
``can``
    python-can on any interface (``socketcan``, ``virtual``, ...). With
    ``protocol: canopen`` (e.g. an Anybus X-gateway) the input area travels
    in TPDO1..4 (COB-ID 0x180/0x280/0x380/0x480 + ``node_id``), the output
    area in RPDO1..4 (0x200/0x300/0x400/0x500 + node id), 8 bytes each, so at
    most 32 bytes per direction; ``sync: true`` sends a SYNC (0x080) before
    each read and waits for that cycle's TPDOs. With ``protocol: raw`` the
    frames are ``input_ids``/``output_ids`` (11-bit), 8 bytes each. Frames
    are received on the event loop (a python-can Notifier); a read uses the
    latest frame of each id if it is at most ``stale_s`` old (older: its
    addresses are left out, i.e. stale) and raises DriverTimeoutError when
    no frame at all came for ``frame_timeout_s``. A write sends every
    output frame (CAN has no reply: a write to a gateway silent for
    ``frame_timeout_s`` raises DriverTimeoutError instead). An ``out:``
    address reads the image this driver last sent: an RPDO cannot be read
    back, so the service does not take it for the PLC's value.

Addresses are byte offsets into the image (:mod:`compd.drivers.gateway.image`),
e.g. ``in:4:int32`` or ``in:12.3``. **32-bit consistency:** a CAN frame is
one gateway cycle, so a multi-byte value split over two frames could pair
halves of two cycles; the config rejects such an address. Over Modbus TCP
the whole area is one request, hence consistent.

Gateway status (``status``): the gateway toggles a live bit every cycle and
holds an "ok" bit while its DP side is in data exchange. A read raises
DriverProtocolError when the ok bit is clear and DriverTimeoutError when the
live bit has not toggled for ``live_timeout_s`` (a frozen gateway serving
old data). compd toggles its own live bit (``output_live``) on every write,
so the PLC can watch compd the same way. Ages and timeouts are bus time
(monotonic seconds), not the service clock: a replayed shift runs faster
than any bus.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import Callable, Hashable, Mapping, Sequence
from pathlib import Path
from typing import Protocol

from compd.drivers.base import RawReading
from compd.drivers.endpoints import modbus_units
from compd.drivers.gateway.image import (
    BYTE_TYPES,
    SYNTAX,
    ImagePoint,
    check_in_area,
    check_one_frame,
    frame_of,
    parse_address,
)
from compd.drivers.gateway.modbus import ModbusTransport
from compd.drivers.gateway.settings import FRAME_BYTES, GatewaySettings
from compd.drivers.gateway.status import StatusWatch
from compd.drivers.points import INT_RANGES
from compd.errors import DriverDisconnectedError, DriverProtocolError


class Transport(Protocol):
    """One side of a gateway: the input area in, the output area out."""

    where: str

    async def open(self) -> None: ...

    async def read_input(self) -> tuple[bytes, frozenset[int] | None]:
        """The input image and the indexes of its fresh frames (``None``: all fresh)."""
        ...

    async def write_output(self, image: bytes) -> None: ...

    async def close(self) -> None: ...


class GatewayDriver:
    """A Profibus DP gateway's byte image over Modbus TCP or CAN; see the module docstring."""

    settings_model = GatewaySettings
    #: Shown in config errors as the fix for a bad address.
    address_syntax = SYNTAX

    def __init__(
        self, settings: GatewaySettings, *, now: Callable[[], float], base_dir: Path
    ) -> None:
        self.settings = settings
        self.watch = StatusWatch(settings)
        self._transport: Transport | None = None
        self._lock: asyncio.Lock | None = None
        self._points: dict[str, ImagePoint] = {}
        #: The output area as last written (kept across reconnects: the PLC's view).
        self.output_image = bytes(settings.output_bytes)

    @staticmethod
    def validate_address(
        address: str, *, writable: bool, settings: GatewaySettings | None = None
    ) -> None:
        """Config-time check of one address (grammar, area, CAN frames); ValueError names what is wrong."""
        parsed = parse_address(address)
        if writable and parsed.area == "in":
            raise ValueError("the input area cannot be written; use an out: address")
        if settings is None:
            return
        check_in_area(parsed, input_bytes=settings.input_bytes, output_bytes=settings.output_bytes)
        if settings.transport == "can" and parsed.bit is None:
            check_one_frame(parsed, FRAME_BYTES)
        live = settings.output_live
        if (
            writable
            and live is not None
            and parsed.offset <= live.offset < parsed.end
            and parsed.bit in (None, live.bit)
        ):
            raise ValueError(
                f"it overlaps compd's live bit out:{live.offset}.{live.bit} (output_live)"
            )

    @staticmethod
    def footprint(address: str, settings: GatewaySettings) -> frozenset[tuple[Hashable, ...]]:
        """The ``(endpoint, image, area, byte, bit)`` cells of a value: its one bit, or every bit of its bytes."""
        parsed = parse_address(address)
        bits = range(8) if parsed.bit is None else (parsed.bit,)
        where, image = settings.endpoint(), settings.image()
        return frozenset(
            (where, image, parsed.area, byte, bit)
            for byte in range(parsed.offset, parsed.end)
            for bit in bits
        )

    @staticmethod
    def write_area(settings: GatewaySettings) -> frozenset[tuple[Hashable, ...]]:
        """The output area, written whole on every write: its holding registers (every unit id), or its CAN frames."""
        where = settings.endpoint()
        if settings.transport == "can":
            return frozenset((where, "frame", can_id) for can_id in settings.can_ids("out"))
        first = settings.output_register
        return frozenset(
            (where, unit, "holding", register)
            for unit in modbus_units(settings.device_id, serial=False)
            for register in range(first, first + settings.output_bytes // 2)
        )

    @staticmethod
    def raw_range(address: str, settings: GatewaySettings) -> tuple[int, int] | None:
        """The whole numbers an integer value (a bit: 0-1, a byte type) holds; ``None`` for floats."""
        parsed = parse_address(address)
        return BYTE_TYPES.get(parsed.type) or INT_RANGES.get(parsed.type)

    @staticmethod
    def reads_back(settings: GatewaySettings) -> bool:
        """Over Modbus TCP the output area is read from the gateway; a CAN RPDO cannot be read."""
        return settings.transport == "modbus_tcp"

    async def open(self) -> None:
        await self.close()
        if self.settings.transport == "modbus_tcp":
            transport: Transport = ModbusTransport(self.settings, self.watch)
        else:
            from compd.drivers.gateway.can import CanTransport  # python-can only when used

            transport = CanTransport(self.settings, self.watch)
        self._lock = asyncio.Lock()
        self.watch.reset(time.monotonic())
        await transport.open()
        self._transport = transport

    async def read(self, points: Sequence[str]) -> dict[str, float]:
        return {
            name: point.read(image) for name, (point, image) in (await self._images(points)).items()
        }

    async def read_raw(self, points: Sequence[str]) -> dict[str, RawReading]:
        """The image bytes behind each address (hex, image order; a bit: its byte), and its value."""
        readings: dict[str, RawReading] = {}
        for name, (point, image) in (await self._images(points)).items():
            shown = " ".join(f"{b:02X}" for b in image[point.offset : point.end])
            if point.bit is not None:
                shown = f"{shown} bit {point.bit}"
            readings[name] = RawReading(shown, point.read(image))
        return readings

    async def _images(self, points: Sequence[str]) -> dict[str, tuple[ImagePoint, bytes]]:
        """Each address (fresh ones only) with the image it is read from: input area or output area."""
        transport, lock = self._connection()
        parsed = [(name, self._point(name)) for name in points]
        found: dict[str, tuple[ImagePoint, bytes]] = {}
        if any(p.address.area == "in" for _, p in parsed):
            async with lock:
                image, fresh = await transport.read_input()
            self.watch.check(time.monotonic(), transport.where, fresh)
            for name, point in parsed:
                if point.address.area == "in" and (
                    fresh is None or frame_of(point.offset, FRAME_BYTES) in fresh
                ):
                    found[name] = (point, image)
        if any(p.address.area == "out" for _, p in parsed):
            output = self.output_image
            if isinstance(transport, ModbusTransport):  # the gateway's image, not our copy
                async with lock:
                    output = await transport.read_output()
            for name, point in parsed:
                if point.address.area == "out":
                    found[name] = (point, output)
        return found

    async def write(self, values: Mapping[str, float]) -> None:
        transport, lock = self._connection()
        image = bytearray(self.output_image)
        for name, value in values.items():  # encode and range-check all before sending any
            point = self._point(name)
            if point.address.area != "out":
                raise DriverProtocolError(f"{name}: the input area cannot be written; use out:")
            try:
                point.write(image, value)
            except DriverProtocolError as exc:
                raise DriverProtocolError(f"{name}: {exc}") from exc
        if self.settings.output_live is not None:
            image[self.settings.output_live.offset] ^= 1 << self.settings.output_live.bit
        async with lock:
            await transport.write_output(bytes(image))
        self.output_image = bytes(image)

    async def close(self) -> None:
        transport, self._transport = self._transport, None
        if transport is not None:
            with contextlib.suppress(Exception):  # close() never raises (Driver contract)
                await transport.close()

    # -- internals ----------------------------------------------------------

    def _connection(self) -> tuple[Transport, asyncio.Lock]:
        if self._transport is None or self._lock is None:
            raise DriverDisconnectedError("gateway driver is not open")
        return self._transport, self._lock

    def _point(self, name: str) -> ImagePoint:
        point = self._points.get(name)
        if point is None:
            try:
                self.validate_address(name, writable=False, settings=self.settings)
            except ValueError as exc:
                raise DriverProtocolError(f"bad gateway address {name!r}: {exc}") from exc
            s = self.settings
            point = self._points[name] = ImagePoint(parse_address(name), s.byte_order, s.word_order)
        return point
