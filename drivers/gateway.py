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

Addresses are byte offsets into the image (:mod:`compd.drivers.gateway_image`),
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
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Literal, Protocol

from compd.drivers.gateway_image import (
    BYTE_TYPES,
    MAX_AREA_BYTES,
    SYNTAX,
    ImagePoint,
    check_in_area,
    check_one_frame,
    frame_of,
    parse_address,
)
from compd.drivers.modbus import ModbusDriver, ModbusSettings
from compd.drivers.points import INT_RANGES, Order
from pydantic import BaseModel, ConfigDict, Field, model_validator

from compd.errors import DriverDisconnectedError, DriverProtocolError, DriverTimeoutError

FRAME_BYTES = 8
MAX_PDOS = 4
_MAX_READ_REGISTERS = 125  # Modbus limits: one request per area keeps an area consistent
_MAX_WRITE_REGISTERS = 123


class StatusSettings(BaseModel):
    """Where the gateway's status byte is in the input area, and its bits."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    offset: int = Field(ge=0, description="byte offset in the input area")
    live_bit: int | None = Field(default=None, ge=0, le=7, description="toggles every cycle")
    ok_bit: int | None = Field(default=None, ge=0, le=7, description="set in data exchange")


class OutputLiveSettings(BaseModel):
    """compd's own live bit in the output area, toggled on every write."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    offset: int = Field(ge=0, description="byte offset in the output area")
    bit: int = Field(ge=0, le=7)


class GatewaySettings(BaseModel):
    """``drivers.<name>.settings`` of a ``type: profibus_gateway`` driver."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    transport: Literal["modbus_tcp", "can"] = "modbus_tcp"
    input_bytes: int = Field(ge=1, le=MAX_AREA_BYTES, description="size of the DP input area")
    output_bytes: int = Field(default=0, ge=0, le=MAX_AREA_BYTES, description="DP output area")
    byte_order: Order = Field(default="big", description="default for addresses without byte=")
    word_order: Order = Field(default="big", description="default for addresses without word=")
    request_timeout_s: float = Field(default=0.5, gt=0, description="per request / SYNC cycle")
    # modbus_tcp
    host: str | None = None
    port: int = Field(default=502, ge=1, le=65535)
    device_id: int = Field(default=1, ge=0, le=247)
    input_register: int = Field(default=0, ge=0, le=65535)
    output_register: int = Field(default=0, ge=0, le=65535)
    # can
    interface: str = Field(default="socketcan", description="python-can interface")
    channel: str | None = Field(default=None, description="e.g. can0, vcan0")
    bitrate: int | None = Field(default=None, gt=0)
    protocol: Literal["canopen", "raw"] = "canopen"
    node_id: int = Field(default=1, ge=1, le=127)
    sync: bool = False
    input_ids: tuple[int, ...] = ()
    output_ids: tuple[int, ...] = ()
    stale_s: float = Field(default=0.5, gt=0, description="older frames are stale")
    frame_timeout_s: float = Field(default=1.0, gt=0, description="no frame at all: timeout")
    # status
    status: StatusSettings | None = None
    live_timeout_s: float = Field(default=1.0, gt=0)
    output_live: OutputLiveSettings | None = None

    @model_validator(mode="after")
    def _consistent(self) -> GatewaySettings:
        if self.transport == "modbus_tcp":
            self._check_modbus()
        else:
            self._check_can()
        if self.status is not None:
            if self.status.offset >= self.input_bytes:
                raise ValueError(f"status.offset must be below input_bytes ({self.input_bytes})")
            if self.status.live_bit is not None and self.status.live_bit == self.status.ok_bit:
                raise ValueError("status.live_bit and status.ok_bit must differ")
        if self.output_live is not None and self.output_live.offset >= self.output_bytes:
            raise ValueError(f"output_live.offset must be below output_bytes ({self.output_bytes})")
        return self

    def _check_modbus(self) -> None:
        if not self.host:
            raise ValueError("transport 'modbus_tcp' needs 'host'")
        for name, size, limit in (
            ("input_bytes", self.input_bytes, _MAX_READ_REGISTERS),
            ("output_bytes", self.output_bytes, _MAX_WRITE_REGISTERS),
        ):
            if size % 2 or size > 2 * limit:
                raise ValueError(
                    f"over modbus_tcp {name} must be even and at most {2 * limit} "
                    "(whole registers, one request per area)"
                )
        if self.input_register + self.input_bytes // 2 > 65536:
            raise ValueError("the input area runs past input register 65535")
        if self.output_register + self.output_bytes // 2 > 65536:
            raise ValueError("the output area runs past holding register 65535")

    def _check_can(self) -> None:
        if not self.channel:
            raise ValueError("transport 'can' needs 'channel' (e.g. can0, vcan0)")
        n_in, n_out = self.frames("in"), self.frames("out")
        if self.protocol == "canopen":
            if max(n_in, n_out) > MAX_PDOS:
                raise ValueError(
                    f"CANopen carries at most {MAX_PDOS} PDOs of 8 bytes per direction: "
                    f"input_bytes and output_bytes must be at most {MAX_PDOS * FRAME_BYTES}"
                )
            if self.input_ids or self.output_ids:
                raise ValueError(
                    "input_ids/output_ids are for protocol 'raw'; canopen uses node_id"
                )
            return
        for name, ids, needed in (
            ("input_ids", self.input_ids, n_in),
            ("output_ids", self.output_ids, n_out),
        ):
            if len(ids) != needed:
                raise ValueError(
                    f"protocol 'raw' needs {needed} {name} (one 8-byte frame per 8 bytes of area)"
                )
            if any(not 0 < i <= 0x7FF for i in ids):
                raise ValueError(f"{name} must be 11-bit CAN ids 0x001..0x7FF")
        if len(set(self.input_ids) | set(self.output_ids)) != n_in + n_out:
            raise ValueError("input_ids and output_ids must all differ")

    def frames(self, area: Literal["in", "out"]) -> int:
        """CAN frames (PDOs) carrying an area."""
        size = self.input_bytes if area == "in" else self.output_bytes
        return -(-size // FRAME_BYTES)

    def can_ids(self, area: Literal["in", "out"]) -> tuple[int, ...]:
        """The CAN ids of an area's frames, in image order."""
        if self.protocol == "raw":
            return self.input_ids if area == "in" else self.output_ids
        base = 0x180 if area == "in" else 0x200
        return tuple(base + 0x100 * k + self.node_id for k in range(self.frames(area)))


class StatusWatch:
    """The gateway's status byte: ok bit and live-bit toggles, fed with every new sample."""

    def __init__(self, settings: GatewaySettings) -> None:
        self.status = settings.status
        self.live_timeout_s = settings.live_timeout_s
        self.reset(time.monotonic())

    def reset(self, now_s: float) -> None:
        self.byte: int | None = None
        self._live: int | None = None
        self.toggled_at_s = self.sampled_at_s = now_s

    def observe(self, byte: int, now_s: float) -> None:
        """One fresh sample of the status byte, received at ``now_s``."""
        if now_s - self.sampled_at_s > self.live_timeout_s:
            # After a silence (judged by the frames' age, not here) the first
            # sample starts a new watch: its bit may equal the last one by chance.
            self._live = None
        self.byte, self.sampled_at_s = byte, now_s
        if self.status is not None and self.status.live_bit is not None:
            live = (byte >> self.status.live_bit) & 1
            if live != self._live:
                self._live, self.toggled_at_s = live, now_s

    def check(self, now_s: float, where: str, fresh: frozenset[int] | None) -> None:
        """Raise if the gateway says its DP side is down, or is frozen.

        Only while the status byte is fresh: a silent gateway is told by its
        frames' age (stale, then DriverTimeoutError), not by its live bit.
        """
        s = self.status
        if s is None or (fresh is not None and frame_of(s.offset, FRAME_BYTES) not in fresh):
            return
        if s.ok_bit is not None and self.byte is not None and not (self.byte >> s.ok_bit) & 1:
            raise DriverProtocolError(
                f"gateway {where}: Profibus side not in data exchange (ok bit {s.ok_bit} of "
                f"status byte {s.offset} is clear): check the DP master and the gateway's DP link"
            )
        if s.live_bit is not None and now_s - self.toggled_at_s > self.live_timeout_s:
            raise DriverTimeoutError(
                f"gateway {where}: live bit {s.live_bit} of status byte {s.offset} has not "
                f"toggled for {now_s - self.toggled_at_s:.2f} s (> live_timeout_s "
                f"{self.live_timeout_s:g}): the gateway is frozen"
            )


class Transport(Protocol):
    """One side of a gateway: the input area in, the output area out."""

    where: str

    async def open(self) -> None: ...

    async def read_input(self) -> tuple[bytes, frozenset[int] | None]:
        """The input image and the indexes of its fresh frames (``None``: all fresh)."""
        ...

    async def write_output(self, image: bytes) -> None: ...

    async def close(self) -> None: ...


class ModbusTransport:
    """The image as input and holding registers; reuses the Modbus driver's requests and errors."""

    def __init__(self, settings: GatewaySettings, watch: StatusWatch) -> None:
        self.settings = settings
        self.watch = watch
        self.where = f"{settings.host}:{settings.port}"
        self._modbus = ModbusDriver(
            ModbusSettings(
                host=settings.host,
                port=settings.port,
                device_id=settings.device_id,
                request_timeout_s=settings.request_timeout_s,
            ),
            now=time.monotonic,
            base_dir=Path(),
        )

    async def open(self) -> None:
        await self._modbus.open()

    async def read_input(self) -> tuple[bytes, frozenset[int] | None]:
        s = self.settings
        client, _ = self._modbus._connection()
        registers = await self._modbus._read_span(
            client, "input", s.input_register, s.input_bytes // 2, s.device_id
        )
        image = b"".join(int(r).to_bytes(2, "big") for r in registers[: s.input_bytes // 2])
        if s.status is not None:
            self.watch.observe(image[s.status.offset], time.monotonic())
        return image, None

    async def read_output(self) -> bytes:
        """The output area as the gateway holds it now (its holding registers)."""
        s = self.settings
        client, _ = self._modbus._connection()
        registers = await self._modbus._read_span(
            client, "holding", s.output_register, s.output_bytes // 2, s.device_id
        )
        return b"".join(int(r).to_bytes(2, "big") for r in registers[: s.output_bytes // 2])

    async def write_output(self, image: bytes) -> None:
        s = self.settings
        client, _ = self._modbus._connection()
        registers = [int.from_bytes(image[i : i + 2], "big") for i in range(0, len(image), 2)]
        last = s.output_register + len(registers) - 1
        await self._modbus._call(
            client.write_registers(s.output_register, registers, device_id=s.device_id),
            f"write output area (holding {s.output_register}..{last})",
        )

    async def close(self) -> None:
        await self._modbus.close()


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
    def footprint(address: str, settings: GatewaySettings) -> frozenset[tuple[str, int, int]]:
        """The ``(area, byte, bit)`` cells of a value: its one bit, or every bit of its bytes."""
        parsed = parse_address(address)
        bits = range(8) if parsed.bit is None else (parsed.bit,)
        return frozenset(
            (parsed.area, byte, bit) for byte in range(parsed.offset, parsed.end) for bit in bits
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
            from compd.drivers.gateway_can import CanTransport  # python-can only when used

            transport = CanTransport(self.settings, self.watch)
        self._lock = asyncio.Lock()
        self.watch.reset(time.monotonic())
        await transport.open()
        self._transport = transport

    async def read(self, points: Sequence[str]) -> dict[str, float]:
        transport, lock = self._connection()
        parsed = [(name, self._point(name)) for name in points]
        values: dict[str, float] = {}
        if any(p.address.area == "in" for _, p in parsed):
            async with lock:
                image, fresh = await transport.read_input()
            self.watch.check(time.monotonic(), transport.where, fresh)
            for name, point in parsed:
                if point.address.area == "in" and (
                    fresh is None or frame_of(point.offset, FRAME_BYTES) in fresh
                ):
                    values[name] = point.read(image)
        if any(p.address.area == "out" for _, p in parsed):
            output = self.output_image
            if isinstance(transport, ModbusTransport):  # the gateway's image, not our copy
                async with lock:
                    output = await transport.read_output()
            for name, point in parsed:
                if point.address.area == "out":
                    values[name] = point.read(output)
        return values

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
