"""Modbus TCP and RTU: read signals from, and write offsets to, a PLC or sensor over Modbus.

Modbus is what most CNC PLCs and temperature scanners speak. One driver
instance is one bus (a TCP connection or a serial line) with one asyncio
lock, so that a tick's requests never interleave with each other.

Addresses are compact strings a PLC engineer can read at a glance::

    TABLE:ADDRESS[:TYPE][:byte=big|little][:word=big|little][:device=N]

    holding:100:int32              holding register 100-101, int32, ABCD
    input:10:float32:word=little   input registers 10-11, float32, CDAB
    coil:3                         coil 3 (bool)
    discrete:0:device=7            discrete input 0 of device 7 on the bus

``TABLE`` is ``holding``, ``input``, ``coil`` or ``discrete``; ``ADDRESS``
is the 0-based protocol address (as on the wire: register number 40101 or
``mbpoll -r 101`` is ``holding:100``). Numbers as manuals write them are
read too, and ``check-config`` notes how: a Modicon reference (``40101``,
``30001:int16``, 6-digit ``400101``; 0x coils, 1x discrete inputs, 3x
input and 4x holding registers, counted from 1) or ``:base=1`` after a
number counted from 1 (``holding:101:base=1`` is ``holding:100``). ``TYPE`` defaults to ``uint16`` for
registers and is always ``bool`` for coils and discrete inputs; the byte and
word orders are those of :mod:`compd.drivers.points`. Scaling to
engineering units stays where it is for every driver: a signal's
``scale``/``offset`` and an output's ``encoding.scale`` in the config
(e.g. ``int32`` offsets in 0.1 um: ``encoding: {type: int, scale: 10}``).

Per tick, the points of one table on one device are sorted and contiguous
(or overlapping) ranges are merged into one request of at most
``max_registers_per_request`` registers; writes of contiguous holding
registers likewise go out as one "write multiple registers"; a written
holding register or coil reads back what the PLC holds. Every value is
encoded and range-checked before the first byte is sent, so a batch with a
value that does not fit writes nothing. pymodbus exceptions and Modbus
exception responses become compd's DriverError family here.
"""

from __future__ import annotations

import asyncio
import contextlib
import struct
from collections.abc import Awaitable, Callable, Hashable, Mapping, Sequence
from pathlib import Path
from typing import Any

from pymodbus.client import AsyncModbusSerialClient, AsyncModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException
from pymodbus.pdu.register_message import (
    ReadHoldingRegistersResponse,
    ReadInputRegistersResponse,
)

from compd.drivers.base import RawReading
from compd.drivers.endpoints import modbus_units
from compd.drivers.library_logs import quiet_library
from compd.drivers.modbus.addresses import (
    BIT_TABLES,
    WRITABLE_TABLES,
    ModbusPoint,
    Table,
    parse_address,
    translation_note,
    word_order_hint,
)
from compd.drivers.modbus.settings import ModbusSettings
from compd.drivers.points import INT_RANGES
from compd.errors import (
    DriverDisconnectedError,
    DriverError,
    DriverProtocolError,
    DriverRefusedError,
    DriverTimeoutError,
)

quiet_library("pymodbus")  # its per-attempt errors and hex dumps: see compd.drivers.library_logs

_MAX_BITS_PER_REQUEST = 2000  # Modbus limit for read coils / discrete inputs
_MAX_WRITE_REGISTERS = 123  # Modbus limit for write multiple registers


def _spans(
    points: list[tuple[str, ModbusPoint]], limit: int
) -> list[list[tuple[str, ModbusPoint]]]:
    """Group points (one table, one device) into runs of contiguous or overlapping ranges.

    A run spans at most ``limit`` registers (or bits); a gap starts a new run,
    since a device may refuse to read addresses it does not have.
    """
    runs: list[list[tuple[str, ModbusPoint]]] = []
    start = end = -1
    for name, point in sorted(points, key=lambda item: item[1].address):
        new_end = max(end, point.address + point.count)
        if runs and point.address <= end and new_end - start <= limit:
            runs[-1].append((name, point))
            end = new_end
        else:
            runs.append([(name, point)])
            start, end = point.address, point.address + point.count
    return runs


class ModbusDriver:
    """Modbus TCP or RTU client; see the module docstring for addresses and batching."""

    settings_model = ModbusSettings
    #: Shown in config errors as the fix for a bad address.
    address_syntax = (
        "as TABLE:ADDRESS[:TYPE][:byte=big|little][:word=big|little][:device=N], "
        "e.g. holding:100:int32 (TABLE holding|input|coil|discrete, ADDRESS 0-based; "
        ":base=1 for ADDRESS counted from 1), or a Modicon reference such as 40101:int32"
    )
    #: How a Modicon or 1-based address was read (``check-config`` shows it).
    address_note = staticmethod(translation_note)

    def __init__(
        self, settings: ModbusSettings, *, now: Callable[[], float], base_dir: Path
    ) -> None:
        self.settings = settings
        self._client: AsyncModbusTcpClient | AsyncModbusSerialClient | None = None
        self._lock: asyncio.Lock | None = None
        #: Requests sent, for tests and benchmarks (one per merged span).
        self.requests = 0

    @staticmethod
    def validate_address(address: str, *, writable: bool, settings: object = None) -> None:
        """Config-time check of one address; ValueError names what is wrong."""
        point = parse_address(address)
        if writable and point.table not in WRITABLE_TABLES:
            raise ValueError(f"a {point.table} cannot be written; use holding or coil")

    @staticmethod
    def footprint(address: str, settings: ModbusSettings) -> frozenset[tuple[Hashable, ...]]:
        """The ``(endpoint, unit, table, register or bit)`` cells a value at ``address`` spans.

        The unit ids a value may reach are those of :func:`compd.drivers.endpoints.modbus_units`:
        on Modbus TCP every one unless ``unit_ids: separate``, on a serial
        line its own (every one for the broadcast id 0).
        """
        point = parse_address(address)
        device = settings.device_id if point.device_id is None else point.device_id
        where = settings.endpoint()
        span = range(point.address, point.address + point.count)
        units = modbus_units(
            device, serial=settings.transport == "rtu", separate=settings.unit_ids == "separate"
        )
        return frozenset((where, unit, point.table, a) for unit in units for a in span)

    @staticmethod
    def exclusive_line(settings: ModbusSettings) -> Hashable | None:
        """On RTU the serial line (one master per bus); Modbus TCP servers take many clients."""
        return settings.endpoint() if settings.transport == "rtu" else None

    @staticmethod
    def raw_range(address: str, settings: ModbusSettings) -> tuple[int, int] | None:
        """The whole numbers an integer point (or a coil: 0-1) holds; ``None`` for floats."""
        return INT_RANGES.get(parse_address(address).codec.type)

    @staticmethod
    def reads_back(settings: ModbusSettings) -> bool:
        """Holding registers and coils read back what the PLC holds now."""
        return True

    async def open(self) -> None:
        await self.close()
        s = self.settings
        # reconnect_delay=0: compd's link supervisor owns reconnects (with
        # backoff), so pymodbus must not reconnect behind its back.
        common: dict[str, Any] = {
            "timeout": s.request_timeout_s,
            "retries": 0,
            "reconnect_delay": 0,
        }
        if s.transport == "tcp":
            assert s.host is not None  # checked by ModbusSettings
            client: AsyncModbusTcpClient | AsyncModbusSerialClient = AsyncModbusTcpClient(
                s.host, port=s.port, **common
            )
        else:
            assert s.serial_port is not None
            client = AsyncModbusSerialClient(
                s.serial_port,
                baudrate=s.baudrate,
                parity=s.parity,
                stopbits=s.stopbits,
                bytesize=s.bytesize,
                **common,
            )
        for strict in _STRICT_REPLIES:
            client.register(strict)
        self._lock = asyncio.Lock()
        where = self._where()
        try:
            connected = await client.connect()
        except (ModbusException, OSError) as exc:
            client.close()
            raise DriverDisconnectedError(f"Modbus {where}: cannot connect: {exc}") from exc
        if not connected:
            client.close()
            raise DriverDisconnectedError(f"Modbus {where}: cannot connect")
        self._client = client

    async def read(self, points: Sequence[str]) -> dict[str, float]:
        fetched = await self._fetch(points)
        return {name: _decode(point, words) for name, (point, words) in fetched.items()}

    async def read_raw(self, points: Sequence[str]) -> dict[str, RawReading]:
        """The registers (hex words, wire order) or the bit behind each address, and its value.

        A value of several registers at an address without ``word=`` carries
        :func:`~compd.drivers.modbus.addresses.word_order_hint`: both word
        orders' readings when they differ, or that all 0 cannot tell them apart.
        """
        fetched = await self._fetch(points)
        readings = {}
        for name, (point, words) in fetched.items():
            if point.table in BIT_TABLES:
                readings[name] = RawReading(str(int(bool(words[0]))), _decode(point, words))
                continue
            registers = [int(w) for w in words]
            readings[name] = RawReading(
                " ".join(f"0x{w:04X}" for w in registers),
                _decode(point, registers),
                hint=word_order_hint(name, registers),
            )
        return readings

    async def _fetch(
        self, points: Sequence[str]
    ) -> dict[str, tuple[ModbusPoint, list[int] | list[bool]]]:
        """Each address's point and its registers (or bit), read in merged spans under the lock."""
        client, lock = self._connection()
        groups: dict[tuple[int, str], list[tuple[str, ModbusPoint]]] = {}
        for name in points:
            point = self._parse(name)
            device = self.settings.device_id if point.device_id is None else point.device_id
            groups.setdefault((device, point.table), []).append((name, point))
        fetched: dict[str, tuple[ModbusPoint, list[int] | list[bool]]] = {}
        async with lock:
            for (device, table), members in groups.items():
                limit = (
                    _MAX_BITS_PER_REQUEST
                    if table in BIT_TABLES
                    else self.settings.max_registers_per_request
                )
                for run in _spans(members, limit):
                    start = run[0][1].address
                    count = max(p.address + p.count for _, p in run) - start
                    words = await self._read_span(client, table, start, count, device)
                    for name, point in run:
                        offset = point.address - start
                        fetched[name] = (point, words[offset : offset + point.count])
        return fetched

    async def write(self, values: Mapping[str, float]) -> None:
        client, lock = self._connection()
        # Encode (and range-check) everything before sending anything.
        registers: dict[int, list[tuple[int, list[int]]]] = {}
        coils: dict[int, list[tuple[int, bool]]] = {}
        for name, value in values.items():
            point = self._parse(name)
            device = self.settings.device_id if point.device_id is None else point.device_id
            if point.table == "holding":
                try:
                    encoded = point.codec.encode_registers(value)
                except DriverProtocolError as exc:
                    raise DriverProtocolError(f"{name}: {exc}") from exc
                registers.setdefault(device, []).append((point.address, encoded))
            elif point.table == "coil":
                if value not in (0.0, 1.0):
                    raise DriverProtocolError(f"{name}: a coil takes 0 or 1, not {value}")
                coils.setdefault(device, []).append((point.address, bool(value)))
            else:
                raise DriverProtocolError(f"{name}: a {point.table} cannot be written")
        async with lock:
            for device, items in registers.items():
                for start, block in _merge_writes(items):
                    await self._call(
                        client.write_registers(start, block, device_id=device),
                        f"write holding {start}..{start + len(block) - 1} of device {device}",
                    )
            for device, bits in coils.items():
                for address, bit in bits:
                    await self._call(
                        client.write_coil(address, bit, device_id=device),
                        f"write coil {address} of device {device}",
                    )

    async def close(self) -> None:
        client, self._client = self._client, None
        if client is not None:
            with contextlib.suppress(Exception):  # close() never raises (Driver contract)
                client.close()

    # -- single requests --------------------------------------------------
    # Public so that a driver built on Modbus (the Profibus gateway's Modbus
    # transport) reuses this driver's connection, request counting and error
    # translation instead of its internals. Neither takes the bus lock: the
    # caller serialises its requests (the gateway holds its own lock).

    async def read_span(
        self, table: Table, start: int, count: int, *, device: int
    ) -> list[int] | list[bool]:
        """Read ``count`` registers (or bits) of ``table`` from ``start`` in one request.

        DriverError family on failure, a short reply included.
        """
        client, _ = self._connection()
        return await self._read_span(client, table, start, count, device)

    async def write_registers(
        self, start: int, registers: Sequence[int], *, device: int, what: str
    ) -> None:
        """Write holding registers from ``start`` in one "write multiple registers" request.

        ``what`` names the request in error messages (e.g. the gateway's
        "write output area (holding 0..15)").
        """
        client, _ = self._connection()
        await self._call(client.write_registers(start, list(registers), device_id=device), what)

    # -- internals ----------------------------------------------------------

    def _connection(self) -> tuple[AsyncModbusTcpClient | AsyncModbusSerialClient, asyncio.Lock]:
        if self._client is None or self._lock is None:
            raise DriverDisconnectedError("Modbus driver is not open")
        if not self._client.connected:
            raise DriverDisconnectedError(f"Modbus {self._where()}: connection lost")
        return self._client, self._lock

    def _where(self) -> str:
        s = self.settings
        return f"{s.host}:{s.port}" if s.transport == "tcp" else str(s.serial_port)

    @staticmethod
    def _parse(address: str) -> ModbusPoint:
        try:
            return parse_address(address)
        except ValueError as exc:
            raise DriverProtocolError(f"bad Modbus address {address!r}: {exc}") from exc

    async def _read_span(
        self,
        client: AsyncModbusTcpClient | AsyncModbusSerialClient,
        table: str,
        start: int,
        count: int,
        device: int,
    ) -> list[int] | list[bool]:
        calls: dict[str, Callable[..., Awaitable[Any]]] = {
            "holding": client.read_holding_registers,
            "input": client.read_input_registers,
            "coil": client.read_coils,
            "discrete": client.read_discrete_inputs,
        }
        what = f"read {table} {start}..{start + count - 1} of device {device}"
        reply = await self._call(calls[table](start, count=count, device_id=device), what)
        words: list[int] | list[bool] = reply.bits if table in BIT_TABLES else reply.registers
        # A reply of another length than asked is not an answer to this request;
        # bits come in whole bytes, so a bit reply holds count rounded up to 8.
        expected = -(-count // 8) * 8 if table in BIT_TABLES else count
        if len(words) != expected:
            kind = "short" if len(words) < expected else "long"
            raise DriverProtocolError(
                f"Modbus {self._where()}: {what}: {kind} reply ({len(words)} of {expected})"
            )
        return words

    async def _call(self, request: Awaitable[Any], what: str) -> Any:
        """Await one pymodbus request, translating its failures into DriverError."""
        self.requests += 1
        try:
            reply = await request
        except ConnectionException as exc:
            raise DriverDisconnectedError(f"Modbus {self._where()}: {what}: {exc}") from exc
        except ModbusIOException as exc:
            if self._client is None or not self._client.connected:
                raise DriverDisconnectedError(f"Modbus {self._where()}: {what}: {exc}") from exc
            raise DriverTimeoutError(f"Modbus {self._where()}: {what}: no reply") from exc
        except TimeoutError as exc:
            raise DriverTimeoutError(f"Modbus {self._where()}: {what}: no reply") from exc
        except (ModbusException, ValueError, struct.error) as exc:
            raise DriverProtocolError(f"Modbus {self._where()}: {what}: {exc}") from exc
        except OSError as exc:
            raise DriverDisconnectedError(f"Modbus {self._where()}: {what}: {exc}") from exc
        except DriverError:
            raise
        if reply is None or reply.isError():
            code = getattr(reply, "exception_code", None)
            raise DriverRefusedError(
                f"Modbus {self._where()}: {what}: the device refused "
                f"(exception code {code}{_EXCEPTION_NAMES.get(code or 0, '')})"
            )
        return reply


def _decode(point: ModbusPoint, words: Sequence[int] | Sequence[bool]) -> float:
    """A point's value from its registers (or its bit)."""
    if point.table in BIT_TABLES:
        return 1.0 if words[0] else 0.0
    return point.codec.decode_registers(words)


def _merge_writes(items: list[tuple[int, list[int]]]) -> list[tuple[int, list[int]]]:
    """Merge (address, registers) writes that follow each other into blocks of <= 123 registers."""
    blocks: list[tuple[int, list[int]]] = []
    for address, words in sorted(items):
        if blocks:
            start, block = blocks[-1]
            if start + len(block) == address and len(block) + len(words) <= _MAX_WRITE_REGISTERS:
                block.extend(words)
                continue
        blocks.append((address, list(words)))
    return blocks


_EXCEPTION_NAMES = {
    1: ": illegal function",
    2: ": illegal data address",
    3: ": illegal data value",
    4: ": device failure",
    6: ": device busy",
    10: ": gateway path unavailable",
    11: ": gateway target did not respond",
}


def _checked_byte_count(data: bytes) -> None:
    """A register reply's byte count: even, and exactly the bytes that follow it.

    pymodbus reads registers up to the byte count and drops what follows, so
    a reply of 21 bytes (a frame cut or shifted) would read as 10 registers.
    """
    count = int(data[0]) if data else -1
    if count < 0 or count % 2 or count != len(data) - 1:
        raise ModbusIOException(f"register reply with byte count {count} and {len(data) - 1} bytes")


class _StrictByteCount:
    """A register reply that checks its byte count before pymodbus decodes it."""

    def decode(self, data: bytes) -> None:
        _checked_byte_count(data)
        super().decode(data)  # type: ignore[misc]


class _StrictHoldingRegisters(_StrictByteCount, ReadHoldingRegistersResponse):
    pass


class _StrictInputRegisters(_StrictByteCount, ReadInputRegistersResponse):
    pass


#: Replies decoded strictly: pymodbus drops a malformed frame, and the request times out.
_STRICT_REPLIES = (_StrictHoldingRegisters, _StrictInputRegisters)
