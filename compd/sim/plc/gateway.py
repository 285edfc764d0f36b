"""The simulated Profibus DP gateway: the PLC's DP image served over Modbus TCP or CAN.

One :class:`GatewayServer` stands where one ``type: profibus_gateway``
driver instance connects, built from that instance's settings: a pymodbus
server at ``host:port`` (the input area as input registers from
``input_register``, the output area as holding registers from
``output_register``), or a node on the CAN ``interface:channel`` that sends
the input area as TPDOs / raw frames every ``cycle_s`` (or, with
``sync: true``, on every SYNC) and takes the output area from RPDOs / raw
frames. Values sit in the image exactly as the driver decodes them (the same
:mod:`compd.drivers.gateway.image` codec and default orders), and every
received output frame or register write is reported as
``on_write(address, raw)`` for the output addresses it carries.

Its status byte (the driver's ``status`` setting) behaves like a gateway's:
the live bit toggles every cycle (on Modbus, every read of the input area:
each read is one fresh exchange, so a reader never samples a toggle twice)
and the ok bit is set while the DP side is in data exchange. Faults for
tests: :meth:`stop`/:meth:`start` (a restart), :meth:`freeze` (the live bit
stops), :meth:`set_dp_down` (the ok bit clears), :meth:`send_malformed`
(one input frame with a wrong length).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import struct
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, cast

import can
from pymodbus.constants import ExcCodes
from pymodbus.exceptions import NoSuchIdException
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice
from pymodbus.simulator.simcore import SimCore

from compd.drivers.gateway.can import SYNC_ID, close_bus, frame_sizes, listen, open_bus
from compd.drivers.gateway.driver import GatewayDriver
from compd.drivers.gateway.image import ImagePoint, parse_address
from compd.drivers.gateway.settings import FRAME_BYTES, GatewaySettings
from compd.errors import DriverError
from compd.sim.plc.server import WriteSink, servable

__all__ = ["GatewayServer"]

_READ_INPUT, _READ_HOLDING = 4, 3
_WRITE_HOLDING = (6, 16)


class GatewayServer:
    """A simulated DP gateway for one ``profibus_gateway`` driver; see the module docstring."""

    def __init__(
        self,
        settings: GatewaySettings,
        *,
        inputs: Sequence[str],
        outputs: Sequence[str],
        on_write: WriteSink,
        base_dir: Path,
        cycle_s: float = 0.01,
    ) -> None:
        self.settings = settings
        self.cycle_s = cycle_s
        self.on_write = on_write
        self.input_image = bytearray(settings.input_bytes)
        self.output_image = bytearray(settings.output_bytes)
        self._inputs = {a: self._point(a, writable=False) for a in inputs}
        self._outputs = [(a, self._point(a, writable=True)) for a in outputs]
        self.frozen = False
        self.dp_down = False
        self.cycles = 0
        self.malformed_received = 0
        self._malformed_next = False
        self._modbus: ModbusTcpServer | None = None
        self._bus: can.BusABC | None = None
        self._notifier: can.Notifier | None = None
        self._task: asyncio.Task[None] | None = None
        self._status()

    def _point(self, address: str, *, writable: bool) -> ImagePoint:
        role = "output" if writable else "input"
        try:
            GatewayDriver.validate_address(address, writable=writable, settings=self.settings)
        except ValueError as exc:
            raise ValueError(f"{role} address {address!r}: {exc}") from None
        s = self.settings
        return ImagePoint(parse_address(address), s.byte_order, s.word_order)

    # -- PlcServer ----------------------------------------------------------

    async def start(self) -> None:
        """Listen on Modbus TCP, or join the CAN bus and start the gateway cycle."""
        if self._modbus is not None or self._bus is not None:
            return
        if self.settings.transport == "modbus_tcp":
            await self._start_modbus()
        else:
            self._start_can()

    async def stop(self) -> None:
        """Drop every connection / leave the bus; the images stay (a restart keeps them)."""
        server, self._modbus = self._modbus, None
        if server is not None:
            with contextlib.suppress(Exception):
                server.close()  # the listener and every connection (shutdown(), typed)
            for _ in range(2):  # the connections' transports close on the next turns
                await asyncio.sleep(0)
        task, self._task = self._task, None
        if task is not None:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        notifier, bus = self._notifier, self._bus
        self._notifier = self._bus = None
        await close_bus(notifier, bus)

    def publish(self, values: Mapping[str, float]) -> None:
        """Serve these raw values from now on; all or none (ValueError names the bad one)."""
        staged: list[tuple[ImagePoint, bytes | float]] = []
        for address, raw in values.items():
            point = self._inputs.get(address)
            if point is None:
                raise ValueError(
                    f"{address!r} is not an input address of the gateway; "
                    f"it serves {sorted(self._inputs)}"
                )
            if point.bit is not None and raw not in (0.0, 1.0):
                raise ValueError(f"cannot publish {raw!r} at {address}: a bit holds 0 or 1")
            staged.append((point, raw if point.bit is not None else _encode(address, point, raw)))
        for point, data in staged:
            if isinstance(data, bytes):
                self.input_image[point.offset : point.end] = data
            else:
                point.write(self.input_image, data)

    # -- faults -------------------------------------------------------------

    def freeze(self, frozen: bool = True) -> None:
        """Stop (or resume) toggling the live bit: a hung gateway still serving old data."""
        self.frozen = frozen

    def set_dp_down(self, down: bool = True) -> None:
        """Clear (or set again) the ok bit: the DP side has left data exchange."""
        self.dp_down = down
        self._status(toggle=False)

    def send_malformed(self) -> None:
        """Send the next first input frame with 3 bytes instead of its mapped length (CAN)."""
        self._malformed_next = True

    # -- the gateway cycle --------------------------------------------------

    def _status(self, *, toggle: bool = True) -> None:
        """One gateway cycle's status byte: live bit toggled (unless frozen), ok bit = DP up."""
        self.cycles += 1
        s = self.settings.status
        if s is None:
            return
        byte = self.input_image[s.offset]
        if s.live_bit is not None and toggle and not self.frozen:
            byte ^= 1 << s.live_bit
        if s.ok_bit is not None:
            byte = byte & ~(1 << s.ok_bit) if self.dp_down else byte | (1 << s.ok_bit)
        self.input_image[s.offset] = byte

    def _written(self, start: int, end: int) -> None:
        """Report every output address inside output bytes ``start..end-1``."""
        for address, point in self._outputs:
            if point.offset < end and point.end > start:
                self.on_write(address, point.read(self.output_image))

    # -- Modbus TCP ---------------------------------------------------------

    async def _start_modbus(self) -> None:
        s = self.settings
        host = cast(str, s.host)
        placeholder = SimDevice(id=0, simdata=[SimData(0, datatype=DataType.REGISTERS)])
        server = ModbusTcpServer(placeholder, address=(host, s.port))
        # Own datastore in place of the simulator's: it serves the images
        # and sees every write (pymodbus calls async_getValues/async_setValues).
        server.context = cast(SimCore, _Registers(self))
        try:
            await server.serve_forever(background=True)
        except RuntimeError as exc:
            server.close()
            raise RuntimeError(
                f"simulated gateway cannot listen on {host}:{s.port} (port in use, or "
                f"{host!r} is not an address of this machine): {exc}"
            ) from exc
        self._modbus = server

    # -- CAN ------------------------------------------------------------------

    def _start_can(self) -> None:
        s = self.settings
        try:
            bus = open_bus(s)
        except DriverError as exc:
            raise OSError(f"simulated gateway: {exc}") from exc
        self._in_ids = s.can_ids("in")
        self._in_sizes = frame_sizes(s.input_bytes)
        self._out_index = {can_id: k for k, can_id in enumerate(s.can_ids("out"))}
        self._out_sizes = frame_sizes(s.output_bytes)
        self._bus = bus
        self._notifier = listen(bus, self._on_frame, lambda exc: None)
        if not s.sync:
            self._task = asyncio.get_running_loop().create_task(self._cyclic())

    async def _cyclic(self) -> None:
        """Send the input area every ``cycle_s`` on absolute deadlines (no drift)."""
        loop = asyncio.get_running_loop()
        next_t = loop.time()
        while True:
            self._status()
            self._send_inputs()
            next_t += self.cycle_s
            await asyncio.sleep(max(0.0, next_t - loop.time()))

    def _send_inputs(self) -> None:
        bus = self._bus
        if bus is None:
            return
        for k, (can_id, size) in enumerate(zip(self._in_ids, self._in_sizes, strict=True)):
            data = bytes(self.input_image[k * FRAME_BYTES : k * FRAME_BYTES + size])
            if k == 0 and self._malformed_next:
                self._malformed_next, data = False, data[:3]
            with contextlib.suppress(can.CanError):  # a full queue drops a cycle, as on a bus
                bus.send(can.Message(arbitration_id=can_id, data=data, is_extended_id=False), 0)

    def _on_frame(self, msg: can.Message) -> None:
        if msg.is_extended_id or msg.is_error_frame or msg.is_remote_frame:
            return
        if msg.arbitration_id == SYNC_ID and self.settings.sync:
            self._status()
            self._send_inputs()
            return
        k = self._out_index.get(msg.arbitration_id)
        if k is None:
            return
        size = self._out_sizes[k]
        if msg.dlc != size:
            self.malformed_received += 1
            return
        start = k * FRAME_BYTES
        self.output_image[start : start + size] = msg.data[:size]
        self._written(start, start + size)


class _Registers:
    """The gateway's two areas as pymodbus' datastore (duck-typed: the calls its PDUs make)."""

    def __init__(self, gateway: GatewayServer) -> None:
        self.gateway = gateway
        s = gateway.settings
        self.device_id = s.device_id
        self.inputs = range(s.input_register, s.input_register + s.input_bytes // 2)
        self.holdings = range(s.output_register, s.output_register + s.output_bytes // 2)
        self.status_register = None if s.status is None else s.input_register + s.status.offset // 2

    def device_ids(self) -> list[int]:
        return [self.device_id]

    async def async_getValues(
        self, device_id: int, func_code: int, address: int, count: int = 1
    ) -> list[int] | ExcCodes:
        self._check(device_id)
        span = range(address, address + count)
        if func_code == _READ_INPUT and _inside(span, self.inputs):
            if self.status_register in span:
                self.gateway._status()  # one exchange, one cycle
            return _registers(self.gateway.input_image, address - self.inputs.start, count)
        if func_code == _READ_HOLDING and _inside(span, self.holdings):
            return _registers(self.gateway.output_image, address - self.holdings.start, count)
        return ExcCodes.ILLEGAL_ADDRESS

    async def async_setValues(
        self, device_id: int, func_code: int, address: int, values: Sequence[Any]
    ) -> ExcCodes | None:
        self._check(device_id)
        span = range(address, address + len(values))
        if func_code not in _WRITE_HOLDING or not _inside(span, self.holdings):
            return ExcCodes.ILLEGAL_ADDRESS
        start = 2 * (address - self.holdings.start)
        data = b"".join(int(v).to_bytes(2, "big") for v in values)
        self.gateway.output_image[start : start + len(data)] = data
        self.gateway._written(start, start + len(data))
        return None

    def _check(self, device_id: int) -> None:
        if device_id != self.device_id:
            raise NoSuchIdException(f"the gateway answers as device {self.device_id} only")


def _inside(span: range, area: range) -> bool:
    return len(span) > 0 and span.start >= area.start and span.stop <= area.stop


def _registers(image: bytearray, first: int, count: int) -> list[int]:
    data = image[2 * first : 2 * (first + count)]
    return [int.from_bytes(data[i : i + 2], "big") for i in range(0, len(data), 2)]


def _encode(address: str, point: ImagePoint, raw: float) -> bytes:
    """Bytes for ``raw`` at ``point``; never wrapped (ValueError when it does not fit)."""
    codec = point.codec
    if codec is not None and codec.type in ("float32", "float64") and not math.isfinite(raw):
        # A PLC can hold NaN or infinity in a float (a failed sensor); the
        # codec, made to check compd's own writes, refuses them.
        data: bytes = codec.reorder(struct.pack(">f" if codec.type == "float32" else ">d", raw))
        return data
    if codec is not None:
        raw = servable(codec, raw)  # an integer input saturates; a broken sensor reads its minimum
    try:
        data = point.encode(raw)
        return data
    except DriverError as exc:
        raise ValueError(f"cannot publish {raw!r} at {address}: {exc}") from None
