"""The simulated PLC's Modbus TCP server: serves the twin's signals, reports compd's writes.

One :class:`ModbusPlcServer` stands where one ``type: modbus`` driver
instance connects (``settings.host``:``settings.port``). Its memory holds
exactly the addresses of the config, nothing else, as a PLC programmer maps
them: the inputs compd reads (any table, type and order, any ``device=``)
and the outputs compd writes (holding registers and coils). Values are laid
out by compd's own codec
(:func:`compd.drivers.modbus.addresses.parse_address`), so a published raw
value reads back as that very value through the driver.

Writes are accepted only at output addresses; a write touching an input or
an address the config does not name is refused with Modbus exception 2
(illegal data address), and a request to a device id no address uses with
exception 11 (gateway target did not respond). After each accepted write
request, every output whose registers have all been written (in this request
or, for a value split over several requests, since it was last reported) is
decoded and reported once through ``on_write(address, raw)``.

A fault injector (the soak, :mod:`compd.sim.soak`) may set
:attr:`ModbusPlcServer.rewrite_reply` to rewrite each reply frame on the wire
before it is sent, to play a PLC whose replies are malformed.

pymodbus (3.16) serves the protocol; the memory is this module's own
datastore, put in place of pymodbus' simulator datastore (the object a
server's requests call ``async_getValues``/``async_setValues`` on), since
the simulator's blocks neither know compd's addresses nor report writes.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import struct
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import cast

from pymodbus.constants import ExcCodes
from pymodbus.exceptions import NoSuchIdException
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice
from pymodbus.simulator.simcore import SimCore

from compd.drivers.modbus.addresses import WRITABLE_TABLES, ModbusPoint, parse_address
from compd.drivers.modbus.settings import ModbusSettings
from compd.errors import DriverProtocolError
from compd.sim.plc.server import PlcServerType, WriteSink, servable

__all__ = ["ModbusPlcServer"]

#: Modbus function code -> the table it reads or writes.
_TABLE_OF_FUNCTION: dict[int, str] = {
    1: "coil",
    5: "coil",
    15: "coil",
    2: "discrete",
    3: "holding",
    6: "holding",
    16: "holding",
    22: "holding",
    23: "holding",
    4: "input",
}
_BIT_TABLES = ("coil", "discrete")
#: struct code per point type (``bool`` travels as one unsigned word).
_STRUCT_CODES = {
    "bool": "H",
    "int16": "h",
    "uint16": "H",
    "int32": "i",
    "uint32": "I",
    "float32": "f",
    "float64": "d",
}


@dataclass(eq=False)
class _Output:
    """One output address: the words it spans, and those written since it was last reported."""

    address: str
    point: ModbusPoint
    cells: dict[int, int]
    pending: set[int] = field(default_factory=set)

    @property
    def span(self) -> range:
        return range(self.point.address, self.point.address + self.point.count)

    def value(self) -> float:
        if self.point.table in _BIT_TABLES:
            return 1.0 if self.cells[self.point.address] else 0.0
        value: float = self.point.codec.decode_registers([self.cells[a] for a in self.span])
        return value


class _Memory:
    """The PLC's memory: ``(device, table) -> {address: word or bit}``, duck-typed as pymodbus' datastore."""

    def __init__(self, on_write: WriteSink) -> None:
        self.cells: dict[tuple[int, str], dict[int, int]] = {}
        self.writable: dict[tuple[int, str], set[int]] = {}
        self.outputs_at: dict[tuple[int, str, int], list[_Output]] = {}
        self.devices: set[int] = set()
        self.on_write = on_write

    def table(self, device: int, table: str) -> dict[int, int]:
        self.devices.add(device)
        return self.cells.setdefault((device, table), {})

    # -- the calls pymodbus' request PDUs make ------------------------------

    def device_ids(self) -> list[int]:
        return sorted(self.devices)

    async def async_getValues(
        self, device_id: int, func_code: int, address: int, count: int = 1
    ) -> list[int] | list[bool] | ExcCodes:
        table, cells = self._lookup(device_id, func_code)
        try:
            words = [cells[a] for a in range(address, address + count)]
        except KeyError:
            return ExcCodes.ILLEGAL_ADDRESS
        return [bool(w) for w in words] if table in _BIT_TABLES else words

    async def async_setValues(
        self,
        device_id: int,
        func_code: int,
        address: int,
        values: Sequence[int] | Sequence[bool],
    ) -> ExcCodes | None:
        table, cells = self._lookup(device_id, func_code)
        writable = self.writable.get((device_id, table), set())
        span = range(address, address + len(values))
        if table not in WRITABLE_TABLES or not all(a in writable for a in span):
            return ExcCodes.ILLEGAL_ADDRESS
        done: list[_Output] = []
        for a, word in zip(span, values, strict=True):
            cells[a] = int(word)
            for output in self.outputs_at[(device_id, table, a)]:
                output.pending.add(a)
                if len(output.pending) == output.point.count and output not in done:
                    done.append(output)
        for output in done:
            output.pending.clear()
            self.on_write(output.address, output.value())
        return None

    def _lookup(self, device_id: int, func_code: int) -> tuple[str, dict[int, int]]:
        if device_id not in self.devices:
            raise NoSuchIdException(f"no address of this PLC uses device {device_id}")
        table = _TABLE_OF_FUNCTION.get(func_code)
        if table is None:  # pymodbus decodes no other data functions; be explicit anyway
            raise NoSuchIdException(f"function {func_code} has no table")
        return table, self.cells.get((device_id, table), {})


class ModbusPlcServer:
    """A Modbus TCP PLC serving the published inputs and reporting writes; see the module docstring."""

    def __init__(
        self,
        settings: ModbusSettings,
        *,
        inputs: Sequence[str],
        outputs: Sequence[str],
        on_write: WriteSink,
        base_dir: Path,
    ) -> None:
        if settings.transport != "tcp" or settings.host is None:
            raise ValueError(
                f"the simulated PLC serves Modbus TCP only, not transport {settings.transport!r}; "
                "set the driver's 'transport: tcp' with 'host' and 'port' for a simulated machine"
            )
        self.settings = settings
        self._memory = _Memory(on_write)
        #: Input address -> (its cells, first address, encoder): what publish() writes to.
        self._slots: dict[str, tuple[dict[int, int], int, _Encoder]] = {}
        self._server: ModbusTcpServer | None = None
        #: Set: every reply frame (MBAP header and PDU) goes through it before it is sent.
        self.rewrite_reply: Callable[[bytes], bytes] | None = None
        for address in inputs:
            point = _parse(address, "input")
            cells = self._memory.table(_device(point, settings), point.table)
            for a in range(point.address, point.address + point.count):
                cells.setdefault(a, 0)
            self._slots[address] = (cells, point.address, _Encoder(address, point))
        for address in outputs:
            point = _parse(address, "output")
            if point.table not in WRITABLE_TABLES:
                raise ValueError(
                    f"output address {address!r}: a {point.table} cannot be written; "
                    "use a holding register or a coil"
                )
            device = _device(point, settings)
            cells = self._memory.table(device, point.table)
            output = _Output(address, point, cells)
            for a in output.span:
                cells.setdefault(a, 0)
                self._memory.writable.setdefault((device, point.table), set()).add(a)
                self._memory.outputs_at.setdefault((device, point.table, a), []).append(output)

    @property
    def address(self) -> tuple[str, int]:
        """``(host, port)`` the server listens on."""
        assert self.settings.host is not None  # checked in __init__
        return self.settings.host, self.settings.port

    async def start(self) -> None:
        """Listen on ``host:port`` (SO_REUSEADDR, so a restart rebinds at once)."""
        if self._server is not None:
            return
        # pymodbus builds its simulator datastore from a device; this one is
        # replaced by the PLC's memory before the first connection.
        placeholder = SimDevice(id=0, simdata=[SimData(0, datatype=DataType.REGISTERS)])
        server = ModbusTcpServer(placeholder, address=self.address, trace_packet=self._trace)
        server.context = cast(SimCore, self._memory)
        try:
            await server.serve_forever(background=True)
        except RuntimeError as exc:  # pymodbus logs the OSError and says only this
            server.close()
            host, port = self.address
            raise RuntimeError(
                f"simulated Modbus PLC cannot listen on {host}:{port} (port in use, or "
                f"{host!r} is not an address of this machine): {exc}"
            ) from exc
        self._server = server

    def _trace(self, sending: bool, packet: bytes) -> bytes:
        """pymodbus' ``trace_packet`` hook: a reply about to be sent, rewritten where asked."""
        rewrite = self.rewrite_reply
        return rewrite(packet) if sending and rewrite is not None else packet

    async def stop(self) -> None:
        """Close the listener and every client connection; published values stay."""
        server, self._server = self._server, None
        if server is None:
            return
        with contextlib.suppress(Exception):  # stop never raises (PlcServer contract)
            server.close()  # the listener and every connection (what shutdown() does, typed)
        # The connections' transports close on the next turns of the loop.
        for _ in range(2):
            await asyncio.sleep(0)

    def publish(self, values: Mapping[str, float]) -> None:
        """Serve these raw values from now on; all or none (ValueError names the bad one)."""
        staged: list[tuple[dict[int, int], int, list[int]]] = []
        for address, raw in values.items():
            try:
                cells, start, encode = self._slots[address]
            except KeyError:
                raise ValueError(
                    f"{address!r} is not an input address of the Modbus PLC at "
                    f"{self.address[0]}:{self.address[1]}; it serves {sorted(self._slots)}"
                ) from None
            staged.append((cells, start, encode(raw)))
        for cells, start, words in staged:
            for i, word in enumerate(words):
                cells[start + i] = word


_: PlcServerType = ModbusPlcServer  # mypy checks the class against the server contract


def _parse(address: str, role: str) -> ModbusPoint:
    try:
        return parse_address(address)
    except ValueError as exc:
        raise ValueError(f"{role} address {address!r}: {exc}") from None


def _device(point: ModbusPoint, settings: ModbusSettings) -> int:
    device: int = settings.device_id if point.device_id is None else point.device_id
    return device


class _Encoder:
    """Raw value -> wire words (or one bit) of one input point, never wrapped (ValueError when it does not fit).

    The codec's own range check and rounding (``codec.raw_for``), then two
    precompiled structs: the same words as ``codec.encode_registers`` (the
    tests compare every type and order) at a fraction of its cost, since
    publish() encodes every signal every simulated second. NaN and infinity
    pass into float types: a PLC holds them for a failed sensor, whereas the
    codec, made to check compd's own writes, refuses them.
    """

    def __init__(self, address: str, point: ModbusPoint) -> None:
        codec = point.codec
        self.address = address
        self.point = point
        self.bit = point.table in _BIT_TABLES
        self.float = codec.type in ("float32", "float64")
        self.pack = struct.Struct(">" + _STRUCT_CODES[codec.type]).pack
        # Two bytes of a word in wire order are one big-endian register, or a
        # little-endian one when the point swaps the bytes inside its words.
        word_code = "<" if codec.byte_order == "little" else ">"
        self.unpack = struct.Struct(word_code + "H" * codec.words).unpack
        self.reverse = codec.word_order == "little"

    def __call__(self, raw: float) -> list[int]:
        if self.bit:
            if raw not in (0.0, 1.0):
                raise ValueError(f"{self.address}: a {self.point.table} holds 0 or 1, not {raw!r}")
            return [int(raw)]
        value: float
        if self.float and not math.isfinite(raw):
            value = raw
        else:
            # A sensor beyond its integer range reads saturated, a broken one the wire-break code.
            try:
                value = self.point.codec.raw_for(servable(self.point.codec, raw))
            except DriverProtocolError as exc:
                raise ValueError(f"cannot publish {raw!r} at {self.address}: {exc}") from None
        words = list(self.unpack(self.pack(value)))
        if self.reverse:
            words.reverse()
        return words
