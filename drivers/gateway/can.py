"""The CAN side of a Profibus gateway: the input area from TPDOs / raw frames, the output area out.

Frames are received by a python-can :class:`can.Notifier` feeding the
running event loop (the loop's own file-descriptor reader for SocketCAN; for
interfaces without a descriptor, e.g. ``virtual``, a reader thread handing
each frame to the loop), so nothing blocks the loop. Frame ``k`` of an area carries image bytes
``8k .. 8k+7``; the latest frame of each id is copied into the input image
with its arrival time. A frame whose length differs from its PDO's mapped
length (its DLC or its data) is not used, and the next read raises
DriverProtocolError naming it.
python-can exceptions become compd's DriverError family here.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import can

from compd.drivers.gateway.settings import FRAME_BYTES, GatewaySettings
from compd.errors import DriverDisconnectedError, DriverProtocolError, DriverTimeoutError

if TYPE_CHECKING:
    from compd.drivers.gateway.status import StatusWatch

SYNC_ID = 0x080


def frame_sizes(size: int) -> list[int]:
    """Bytes carried by each 8-byte frame of an area of ``size`` bytes (the last may be shorter)."""
    return [min(FRAME_BYTES, size - start) for start in range(0, size, FRAME_BYTES)]


def open_bus(settings: GatewaySettings) -> can.BusABC:
    """A python-can bus for the settings; DriverDisconnectedError if the interface cannot be opened."""
    options: dict[str, Any] = {"interface": settings.interface, "channel": settings.channel}
    if settings.bitrate is not None:
        options["bitrate"] = settings.bitrate
    try:
        return can.Bus(**options)
    except (can.CanError, OSError, ValueError, ImportError, NotImplementedError) as exc:
        raise DriverDisconnectedError(
            f"CAN {settings.interface}:{settings.channel}: cannot open the interface: {exc}"
        ) from exc


class _OnLoop(can.Listener):
    """Hands every frame and reader error to callbacks run on ``loop`` (from any thread)."""

    def __init__(
        self,
        loop: asyncio.AbstractEventLoop | None,
        on_frame: Callable[[can.Message], None],
        on_error: Callable[[Exception], None],
    ) -> None:
        self.loop, self.frame, self.error = loop, on_frame, on_error

    def on_message_received(self, msg: can.Message) -> None:
        self._call(self.frame, msg)

    def on_error(self, exc: Exception) -> None:
        self._call(self.error, exc)

    def _call(self, callback: Callable[[Any], None], arg: Any) -> None:
        if self.loop is None:  # already on the loop (a file-descriptor reader)
            callback(arg)
            return
        # A reader thread outliving its loop (a loop closed with the bus
        # still open) must not die with a traceback: drop the frame.
        with contextlib.suppress(RuntimeError):
            self.loop.call_soon_threadsafe(callback, arg)


def listen(
    bus: can.BusABC,
    on_frame: Callable[[can.Message], None],
    on_error: Callable[[Exception], None],
) -> can.Notifier:
    """Receive on the running loop: its reader for a bus with a file descriptor, else a thread."""
    loop = asyncio.get_running_loop()
    try:
        has_fd = bus.fileno() >= 0
    except NotImplementedError:
        has_fd = False
    if has_fd:
        return can.Notifier(bus, [_OnLoop(None, on_frame, on_error)], timeout=0.1, loop=loop)
    return can.Notifier(bus, [_OnLoop(loop, on_frame, on_error)], timeout=0.1)


class CanTransport:
    """The gateway's image over CAN (CANopen PDOs or raw frames); see the module docstring."""

    def __init__(self, settings: GatewaySettings, watch: StatusWatch) -> None:
        self.settings = settings
        self.watch = watch
        self.where = f"CAN {settings.interface}:{settings.channel}"
        self.in_ids = settings.can_ids("in")
        self.out_ids = settings.can_ids("out")
        self._in_sizes = frame_sizes(settings.input_bytes)
        self._out_sizes = frame_sizes(settings.output_bytes)
        self._index = {can_id: k for k, can_id in enumerate(self.in_ids)}
        self._status_frame = -1 if settings.status is None else settings.status.offset // 8
        self.image = bytearray(settings.input_bytes)
        self.received_s = [-math.inf] * len(self.in_ids)
        self.counts = [0] * len(self.in_ids)
        self.malformed: str | None = None
        self.bus_error: Exception | None = None
        self._bus: can.BusABC | None = None
        self._notifier: can.Notifier | None = None
        self._arrived: asyncio.Event | None = None

    def on_frame(self, msg: can.Message) -> None:
        """Store one received frame (on the loop): the latest of each id, with its arrival time."""
        k = self._index.get(msg.arbitration_id)
        if k is None or msg.is_extended_id or msg.is_error_frame or msg.is_remote_frame:
            return
        size = self._in_sizes[k]
        if msg.dlc != size or len(msg.data) != size:
            # The data's own length too: a frame whose DLC says 8 over 1 byte of data
            # would shift every byte of the image behind it.
            carried = f"{len(msg.data)}" + ("" if msg.dlc == len(msg.data) else f" (DLC {msg.dlc})")
            self.malformed = (
                f"frame 0x{msg.arbitration_id:03X} carried {carried} bytes, expected {size}"
            )
            return
        # Arrival on the bus, not here: frames queued while the loop was busy are that old.
        age_s = time.time() - msg.timestamp
        now_s = time.monotonic() - (age_s if 0 < age_s < 60 else 0.0)
        start = k * FRAME_BYTES
        self.image[start : start + size] = msg.data[:size]
        self.received_s[k] = now_s
        self.counts[k] += 1
        if k == self._status_frame and self.settings.status is not None:
            self.watch.observe(self.image[self.settings.status.offset], now_s)
        if self._arrived is not None:
            self._arrived.set()

    async def open(self) -> None:
        await self.close()
        self.bus_error, self.malformed = None, None
        self.received_s = [-math.inf] * len(self.in_ids)
        self._arrived = asyncio.Event()
        bus = open_bus(self.settings)
        self._bus = bus
        try:
            self._notifier = listen(bus, self.on_frame, self._on_error)
        except (can.CanError, OSError, ValueError) as exc:
            await self.close()
            raise DriverDisconnectedError(f"{self.where}: cannot listen: {exc}") from exc
        # A gateway that sends nothing is not there: wait for one full input image.
        if not await self._cycle(self.settings.frame_timeout_s):
            await self.close()
            raise DriverTimeoutError(
                f"{self.where}: no input frames {self._ids_text()} within "
                f"{self.settings.frame_timeout_s:g} s: is the gateway powered and on this bus?"
            )

    async def read_input(self) -> tuple[bytes, frozenset[int] | None]:
        await asyncio.sleep(0)  # take in the frames already handed to the loop
        self._check_bus()
        if self.malformed is not None:
            text, self.malformed = self.malformed, None
            raise DriverProtocolError(f"{self.where}: malformed frame: {text}")
        if self.settings.sync:
            await self._cycle(self.settings.request_timeout_s)
        now_s = time.monotonic()
        newest_s = max(self.received_s)
        if now_s - newest_s > self.settings.frame_timeout_s:
            raise DriverTimeoutError(
                f"{self.where}: no frame {self._ids_text()} for more than "
                f"{self.settings.frame_timeout_s:g} s"
            )
        stale_s = self.settings.stale_s
        fresh = frozenset(k for k, t in enumerate(self.received_s) if now_s - t <= stale_s)
        return bytes(self.image), fresh

    async def write_output(self, image: bytes) -> None:
        bus = self._check_bus()
        # CAN has no reply to a write: a gateway silent for frame_timeout_s
        # would not receive it either, so say so instead of writing to nobody.
        silent_s = time.monotonic() - max(self.received_s)
        if silent_s > self.settings.frame_timeout_s:
            raise DriverTimeoutError(
                f"{self.where}: not written: no frame from the gateway for {silent_s:.2f} s"
            )
        for k, (can_id, size) in enumerate(zip(self.out_ids, self._out_sizes, strict=True)):
            start = k * FRAME_BYTES
            self._send(bus, can_id, image[start : start + size])

    async def close(self) -> None:
        notifier, bus = self._notifier, self._bus
        self._notifier = self._bus = None
        await close_bus(notifier, bus)

    # -- internals ----------------------------------------------------------

    def _on_error(self, exc: Exception) -> None:
        self.bus_error = exc

    async def _cycle(self, timeout_s: float) -> bool:
        """Wait until every input frame arrives anew (after a SYNC when ``sync``); False on timeout."""
        assert self._arrived is not None
        before = list(self.counts)
        if self.settings.sync:
            self._send(self._check_bus(), SYNC_ID, b"")
        deadline = asyncio.get_running_loop().time() + timeout_s
        while any(c == b for c, b in zip(self.counts, before, strict=True)):
            self._arrived.clear()
            remaining = deadline - asyncio.get_running_loop().time()
            if remaining <= 0:
                return False
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._arrived.wait(), remaining)
            self._check_bus()
        return True

    def _check_bus(self) -> can.BusABC:
        if self._bus is None or getattr(self._bus, "_is_shutdown", False):
            raise DriverDisconnectedError(f"{self.where}: not open (interface shut down)")
        if self.bus_error is not None:
            raise DriverDisconnectedError(f"{self.where}: receive failed: {self.bus_error}")
        return self._bus

    def _send(self, bus: can.BusABC, can_id: int, data: bytes) -> None:
        msg = can.Message(arbitration_id=can_id, data=data, is_extended_id=False)
        try:
            bus.send(msg, timeout=0)  # never wait on the loop: a full queue is a fault
        except can.CanOperationError as exc:
            if "closed" in str(exc).lower():
                raise DriverDisconnectedError(f"{self.where}: send 0x{can_id:03X}: {exc}") from exc
            raise DriverTimeoutError(
                f"{self.where}: send 0x{can_id:03X}: {exc} (no node acknowledging? bus-off?)"
            ) from exc
        except (can.CanError, OSError) as exc:
            raise DriverDisconnectedError(f"{self.where}: send 0x{can_id:03X}: {exc}") from exc

    def _ids_text(self) -> str:
        return "(" + ", ".join(f"0x{i:03X}" for i in self.in_ids) + ")"


async def close_bus(notifier: can.Notifier | None, bus: can.BusABC | None) -> None:
    """Stop the reader, then leave the bus; never raises (driver and simulated gateway)."""
    if notifier is not None:
        # Joining a reader thread blocks for up to its timeout: not on the loop.
        with contextlib.suppress(Exception):
            await asyncio.to_thread(notifier.stop, 1.0)
    if bus is not None:
        with contextlib.suppress(Exception):
            bus.shutdown()
