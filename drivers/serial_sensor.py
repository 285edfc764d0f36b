"""Serial sensors: multi-channel temperature scanners speaking a line-based ASCII protocol.

Many scanners and temperature loggers on a machine tool (RS-232/RS-485, or a
USB virtual COM port) answer a text request with one text line: the driver
sends ``request`` (a template naming the channels) and parses the reply with a
regular expression whose named groups are ``channel`` and ``value`` (framing,
checksums and parsing: :mod:`compd.drivers.serial_lines`). One request per
poll fetches all channels (``{channels}`` in the template), or one request per
channel (``{channel}``) for instruments that take one at a time::

    request  MEAS? 1,2,3\\r\\n
    reply    1=+23.456,2=+24.101,3=+22.870*5A\\r\\n     (items split on ',', checksum after '*')

A signal's ``address`` is the channel name or number as the instrument spells it.

``poll: on_read`` (default) asks the instrument inside each :meth:`read`, so a
tick waits for the wire: at 9600 baud one 8-channel exchange is ~115 ms.
``poll: background`` asks every ``poll_period_s`` in a task of its own and a
:meth:`read` returns at once the values of the polls completed since the
previous read (none yet: no key, so the loop's ``stale_s`` check still sees a
silent instrument); a failed background poll is raised by the next read.
Either way the driver entry's ``timeout_s`` must cover one whole poll (every
request and reply of it on the wire), since ``open`` in background mode and
every on_read ``read`` runs one under that timeout.

Faults map onto compd's three driver errors and nothing else: a reply that
does not match the pattern, fails its checksum or lacks a requested channel is
a :class:`~compd.errors.DriverProtocolError` and that poll yields no values;
no complete line within ``reply_timeout_s`` (silent instrument, or half a
line) is a :class:`~compd.errors.DriverTimeoutError` and the half line is
dropped, never parsed; a lost port (adapter unplugged) is a
:class:`~compd.errors.DriverDisconnectedError` and a later :meth:`open` opens it
again. A value outside the sensor's declared range (an open thermocouple reads
far off scale) is left out of that read, so that one broken sensor does not
take its neighbours on the same scanner down with it: the loop sees that
channel go stale and applies its ``checks``.

A scanner has nothing to write: :meth:`SerialSensorDriver.write` refuses any
value. Axis offsets, the status word and the heartbeat must be configured on a
driver that reaches the controller (Modbus, OPC UA, ...).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import re
from collections import deque
from collections.abc import Callable, Hashable, Mapping, Sequence
from pathlib import Path
from typing import Any

import serial
import structlog
from serial_asyncio_fast import SerialTransport, connection_for_serial

from compd.drivers.base import RawReading
from compd.drivers.endpoints import serial_endpoint
from compd.drivers.serial_lines import (
    SerialSensorSettings,
    field_value,
    frame_request,
    parse_fields,
    parse_values,
    reply_payload,
)
from compd.errors import (
    DriverDisconnectedError,
    DriverError,
    DriverProtocolError,
    DriverTimeoutError,
)
from compd.faultlog import FaultLog

__all__ = ["SerialSensorDriver", "SerialSensorSettings"]

log = structlog.get_logger("compd.drivers.serial_sensor")

#: A reply line longer than this without a terminator is garbage, not a reply.
MAX_LINE_BYTES = 4096
#: How long :meth:`SerialSensorDriver.close` waits for the port to be released (s).
CLOSE_WAIT_S = 1.0


class _LineProtocol(asyncio.Protocol):
    """Collects received bytes into complete lines; a partial line is never handed out."""

    def __init__(self, terminator: bytes) -> None:
        self.terminator = terminator
        self.buffer = bytearray()
        self.lines: deque[bytes] = deque()
        self.overflowed = False
        self.lost: BaseException | None = None
        self.closed = asyncio.get_running_loop().create_future()
        self._waiter: asyncio.Future[None] | None = None

    def data_received(self, data: bytes) -> None:
        self.buffer += data
        *complete, rest = bytes(self.buffer).split(self.terminator)
        self.lines.extend(complete)
        self.buffer = bytearray(rest)
        if len(self.buffer) > MAX_LINE_BYTES:
            self.buffer.clear()
            self.overflowed = True
        self._wake()

    def connection_lost(self, exc: Exception | None) -> None:
        self.lost = exc or ConnectionError("port closed")
        if not self.closed.done():
            self.closed.set_result(None)
        self._wake()

    def clear(self) -> None:
        """Forget everything received so far (a late reply to an earlier request)."""
        self.buffer.clear()
        self.lines.clear()
        self.overflowed = False

    async def next_line(self) -> bytes:
        """The next complete line; raises when the port is lost or a line overflows."""
        while True:
            if self.lines:
                return self.lines.popleft()
            if self.overflowed:
                raise DriverProtocolError(f"a reply line ran over {MAX_LINE_BYTES} bytes")
            if self.lost is not None:
                raise DriverDisconnectedError(f"serial port lost: {self.lost}")
            self._waiter = asyncio.get_running_loop().create_future()
            try:
                await self._waiter
            finally:
                self._waiter = None

    def _wake(self) -> None:
        if self._waiter is not None and not self._waiter.done():
            self._waiter.set_result(None)


class SerialSensorDriver:
    """Polls a line-based ASCII scanner on a serial port; read-only. See the module docstring."""

    settings_model = SerialSensorSettings

    def __init__(
        self, settings: SerialSensorSettings, *, now: Callable[[], float], base_dir: Path
    ) -> None:
        self.settings = settings
        self._now = now  # unused: timeouts are the event loop's; kept for the DriverType contract
        self._pattern = re.compile(settings.reply)
        self._transport: SerialTransport | None = None
        self._protocol: _LineProtocol | None = None
        self._lock: asyncio.Lock | None = None
        self._poller: asyncio.Task[None] | None = None
        #: Background mode: values polled since the last read, and the last poll's error.
        self._fresh: dict[str, float] = {}
        self._poll_error: DriverError | None = None
        self._missed = 0  # replies missed in a row
        #: Missed replies are a fault episode until a reply comes: one WARNING, not one per miss.
        self._misses = FaultLog(log, level="warning", port=settings.port)
        #: Why each channel's last value was left out (out of range), until it recovers.
        self.rejected: dict[str, str] = {}
        #: Number of successful ``open`` calls.
        self.opens = 0

    async def open(self) -> None:
        """Open the port (again), closing any earlier connection; background mode polls once first."""
        await self.close()
        s = self.settings
        try:
            # Opened here rather than in an executor: a local tty opens in well under a
            # millisecond, and a cancelled executor job would leak the file descriptor.
            port = serial.Serial(
                s.port,
                baudrate=s.baudrate,
                bytesize=s.bytesize,
                parity=s.parity,
                stopbits=s.stopbits,
                exclusive=True,  # the bus lock between processes: one poller per port
            )
        except (OSError, ValueError) as exc:  # SerialException is an OSError
            raise DriverDisconnectedError(f"cannot open serial port {s.port}: {exc}") from exc
        protocol = _LineProtocol(s.reply_terminator.encode("latin-1"))
        loop = asyncio.get_running_loop()
        transport, _ = await connection_for_serial(loop, lambda: protocol, port)
        self._transport, self._protocol = transport, protocol
        self._lock = asyncio.Lock()
        self._fresh, self._poll_error = {}, None
        if s.poll == "background":
            # The first poll in open(): a port that opens but whose instrument does not
            # answer is a failed open, and the first tick finds values.
            try:
                self._fresh = await self._poll(list(s.channels))
            except DriverError:
                await self.close()
                raise
            self._poller = loop.create_task(self._poll_forever(loop.time() + s.poll_period_s))
        self.opens += 1

    async def read(self, points: Sequence[str]) -> dict[str, float]:
        """One value per requested channel, in the instrument's unit; out-of-range values left out."""
        channels = list(dict.fromkeys(points))
        declared = self.settings.channels
        unknown = [c for c in channels if declared and c not in declared]
        if unknown:
            raise DriverProtocolError(
                f"serial sensor on {self.settings.port} has no channel(s) {unknown}; "
                f"it declares {list(declared)}"
            )
        if self.settings.poll == "background":
            return self._take_fresh(channels)
        self._connected()
        return self._in_range(await self._tolerate_misses(channels)) if channels else {}

    async def _tolerate_misses(self, channels: list[str]) -> dict[str, float]:
        """One missed reply leaves the values stale for a tick; ``max_missed_replies`` in a row raise."""
        try:
            raw = await self._poll(channels)
        except DriverTimeoutError:
            self._missed += 1
            if self._missed >= self.settings.max_missed_replies:
                self._missed = 0
                raise
            self._misses.failed("missed reply", in_a_row=self._missed)
            return {}
        self._missed = 0
        self._misses.cleared("replies again")
        return raw

    address_syntax = "as a channel of a signal; put outputs and status on a writable driver"

    @staticmethod
    def validate_address(address: str, *, writable: bool, settings: object = None) -> None:
        """A scanner's channels can be read, never written (``compd check-config`` refuses it)."""
        if writable:
            raise ValueError(
                "a serial sensor is read-only: offsets, status word and heartbeat "
                "must go to the controller's driver"
            )

    @staticmethod
    def exclusive_line(settings: SerialSensorSettings) -> Hashable:
        """The serial port: one request and its reply at a time, from one driver entry."""
        return serial_endpoint(settings.port)

    async def write(self, values: Mapping[str, float]) -> None:
        """Refuse: a scanner is read-only (offsets and status go to the controller's driver)."""
        if values:
            raise DriverProtocolError(
                f"serial sensor on {self.settings.port} is read-only: cannot write "
                f"{sorted(values)}; configure outputs and status on the controller's driver"
            )

    async def close(self) -> None:
        """Stop polling, close the port and wait (briefly) until it is released; never raises."""
        poller, self._poller = self._poller, None
        if poller is not None:
            poller.cancel()
            with contextlib.suppress(asyncio.CancelledError, DriverError):
                await poller
        transport, protocol = self._transport, self._protocol
        self._transport = self._protocol = None
        if transport is None or protocol is None:
            return
        try:
            transport.close()
            # The transport closes the device in a background task; wait for it so a
            # reopen finds the port free (exclusive lock) and no descriptor leaks.
            await asyncio.wait_for(asyncio.shield(protocol.closed), CLOSE_WAIT_S)
        except (OSError, TimeoutError, RuntimeError) as exc:
            log.debug("serial port close failed", port=self.settings.port, error=repr(exc))

    def _connected(self) -> tuple[_LineProtocol, SerialTransport, asyncio.Lock]:
        protocol, transport, lock = self._protocol, self._transport, self._lock
        if protocol is None or transport is None or lock is None:
            raise DriverDisconnectedError(f"serial port {self.settings.port} is not open")
        if protocol.lost is not None or transport.is_closing():
            reason = protocol.lost or "the device hung up"
            raise DriverDisconnectedError(f"serial port {self.settings.port} lost: {reason}")
        return protocol, transport, lock

    async def read_raw(self, points: Sequence[str]) -> dict[str, RawReading]:
        """Each channel's value field as the instrument sent it, from one poll of its own.

        Also in background mode: commissioning wants the reply of now, not the poller's last.
        """
        channels = list(dict.fromkeys(points))
        fields = await self._poll(channels, parse=parse_fields)
        readings: dict[str, RawReading] = {}
        for channel, text in fields.items():
            kept = self._in_range({channel: field_value(self.settings, channel, text)})
            note = "" if channel in kept else self.rejected.get(channel, "")
            readings[channel] = RawReading(repr(text), kept.get(channel), note)
        return readings

    async def _poll(
        self, channels: list[str], parse: Callable[..., dict[str, Any]] = parse_values
    ) -> dict[str, Any]:
        """Ask for ``channels`` (one request, or one per channel) under the bus lock; all or nothing."""
        s = self.settings
        raw: dict[str, Any] = {}
        async with self._connected()[2]:
            if s.per_channel:
                for channel in channels:
                    payload = await self._exchange(channel=channel)
                    raw |= parse(s, self._pattern, payload, [channel])
            else:
                payload = await self._exchange(channels=s.channel_separator.join(channels))
                raw = parse(s, self._pattern, payload, channels)
        return raw

    async def _poll_forever(self, next_s: float) -> None:
        """Background mode: poll on absolute deadlines ``next_s += poll_period_s``; stop when the port is lost."""
        loop = asyncio.get_running_loop()
        channels = list(self.settings.channels)
        while True:
            await asyncio.sleep(max(0.0, next_s - loop.time()))
            # A poll longer than the period skips the missed deadlines instead of bunching up.
            next_s = max(next_s + self.settings.poll_period_s, loop.time())
            try:
                self._fresh |= await self._tolerate_misses(channels)
            except DriverDisconnectedError as exc:
                self._poll_error = exc
                return
            except DriverError as exc:
                self._poll_error = exc

    def _take_fresh(self, channels: list[str]) -> dict[str, float]:
        """Background mode: the requested values polled since the last read, or the poll's error."""
        error, self._poll_error = self._poll_error, None
        if error is not None:
            raise error
        self._connected()  # raises: not open, or the port lost since the last poll
        if self._poller is None or self._poller.done():
            raise DriverDisconnectedError(f"serial port {self.settings.port}: poller stopped")
        fresh = {c: self._fresh.pop(c) for c in channels if c in self._fresh}
        return self._in_range(fresh)

    async def _exchange(self, **fields: str) -> str:
        """Send one request, return the next non-empty reply line's payload, checksum verified."""
        s = self.settings
        protocol, transport, _ = self._connected()
        request, frame = frame_request(s, **fields)
        protocol.clear()  # a late reply to an earlier, timed-out request is not this one's
        transport.write(frame)
        try:
            async with asyncio.timeout(s.reply_timeout_s):
                line = b""
                while not line.strip():
                    line = await protocol.next_line()
        except TimeoutError:
            partial = f" ({len(protocol.buffer)} bytes of an unfinished line dropped)"
            raise DriverTimeoutError(
                f"no reply line from {s.port} within {s.reply_timeout_s} s to {request!r}"
                + (partial if protocol.buffer else "")
            ) from None
        payload: str = reply_payload(s, line)
        return payload

    def _in_range(self, raw: Mapping[str, float]) -> dict[str, float]:
        """``raw`` without values outside their sensor's declared range (logged once per episode)."""
        values: dict[str, float] = {}
        for channel, value in raw.items():
            low, high = (
                self.settings.channel_ranges.get(channel)
                or self.settings.range
                or (
                    -math.inf,
                    math.inf,
                )
            )
            if math.isfinite(value) and low <= value <= high:
                values[channel] = value
                if self.rejected.pop(channel, None) is not None:
                    log.info("sensor value back in range", port=self.settings.port, channel=channel)
                continue
            reason = f"{value!r} outside the sensor's range [{low}, {high}]"
            if channel not in self.rejected:
                log.error(
                    "sensor value out of range",
                    port=self.settings.port,
                    channel=channel,
                    value=value,
                )
            else:
                log.debug("sensor value still out of range", channel=channel, value=value)
            self.rejected[channel] = reason
        return values
