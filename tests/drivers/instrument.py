"""A simulated multi-channel temperature scanner on a pseudo-terminal, for the serial driver's tests.

The instrument owns a pty pair (:func:`os.openpty`): the driver opens the
slave side like any serial port, a thread answers on the master side. The
port is reached through a stable symlink (``port``), as a udev rule gives a
USB adapter ``/dev/serial/by-id/...``: :meth:`PtyInstrument.unplug` closes the
pty (the driver's port hangs up) and removes the link, :meth:`plug` makes a
new pty behind the same link.

Protocol (the driver's defaults): a request ``MEAS? 1,2,3\\r\\n`` (a checksum
``*HH`` before the terminator is accepted and checked when ``checksum`` is
set) is answered ``1=+23.456,2=+24.101,3=+22.870\\r\\n``, with ``*HH`` (XOR
of the payload) before the terminator when ``checksum`` is set. An unknown
channel is answered ``ERR unknown channel 9``. ``mode`` injects faults into
the following replies: ``garbled``, ``partial`` (the first half of the line,
never finished), ``silent`` (no reply), ``bad_checksum``; ``reply_override``
replaces every reply with the bytes a test chose.
"""

from __future__ import annotations

import os
import select
import threading
import tty
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Literal

Mode = Literal["ok", "garbled", "partial", "silent", "bad_checksum"]


def xor_hex(data: bytes) -> str:
    """Two hex digits: the XOR of ``data``'s bytes (written independently of the driver's)."""
    total = 0
    for byte in data:
        total ^= byte
    return f"{total:02X}"


def answer(
    request: str, values: Mapping[str, float], *, checksum: bool, mode: Mode = "ok"
) -> bytes | None:
    """The scanner's reply to one request line (without terminator), or None for no reply."""
    if checksum and "*" in request:
        request, _, given = request.rpartition("*")
        if given != xor_hex(request.encode()):
            return b"ERR checksum\r\n"
    command, _, argument = request.partition(" ")
    if command != "MEAS?":
        return b"ERR unknown command\r\n"
    items = []
    for channel in argument.split(","):
        if channel not in values:
            return f"ERR unknown channel {channel}\r\n".encode()
        items.append(f"{channel}={values[channel]:+.3f}")
    payload = ",".join(items)
    if mode == "garbled":
        payload = payload.replace("=", "#").replace(",", "?\x7f")
    suffix = ""
    if checksum:
        digits = xor_hex(payload.encode())
        suffix = "*" + (f"{int(digits, 16) ^ 0x5A:02X}" if mode == "bad_checksum" else digits)
    line = f"{payload}{suffix}\r\n".encode()
    if mode == "silent":
        return None
    if mode == "partial":
        return line[: len(line) // 2]
    return line


class PtyInstrument:
    """A scanner answering on a pty behind the symlink ``port``; see the module docstring."""

    def __init__(self, link: Path, values: dict[str, float], *, checksum: bool = False) -> None:
        self.port = link
        self.values = dict(values)
        self.checksum = checksum
        self.mode: Mode = "ok"
        #: When set, the bytes sent back for every request instead of the answer.
        self.reply_override: bytes | None = None
        #: Requests received (decoded, without terminator), in order.
        self.requests: list[str] = []
        self._master = self._slave = -1
        self._stop_r = self._stop_w = -1
        self._thread: threading.Thread | None = None
        self.plug()

    @property
    def plugged(self) -> bool:
        return self._thread is not None

    def plug(self) -> None:
        """Create a new pty and point ``port`` at its slave; start answering."""
        if self.plugged:
            return
        self._master, self._slave = os.openpty()
        # Raw from the start: no echo of requests back to the driver before it configures the port.
        tty.setraw(self._slave)
        self._stop_r, self._stop_w = os.pipe()
        tmp = self.port.with_name(self.port.name + ".new")
        tmp.unlink(missing_ok=True)
        tmp.symlink_to(os.ttyname(self._slave))
        tmp.replace(self.port)
        self._thread = threading.Thread(target=self._serve, name="pty-instrument", daemon=True)
        self._thread.start()

    def unplug(self) -> None:
        """Stop answering, close the pty (the driver's port hangs up) and remove ``port``."""
        if self._thread is None:
            return
        os.write(self._stop_w, b"x")
        self._thread.join(timeout=5.0)
        self._thread = None
        for fd in (self._master, self._slave, self._stop_r, self._stop_w):
            os.close(fd)
        self.port.unlink(missing_ok=True)

    @contextmanager
    def fault(self, mode: Mode) -> Iterator[None]:
        """Answer in ``mode`` inside the block, normally after it."""
        self.mode = mode
        try:
            yield
        finally:
            self.mode = "ok"

    def reply_for(self, request: str) -> bytes | None:
        """The bytes sent back for one request line (None: no reply); the request is recorded."""
        self.requests.append(request)
        if self.reply_override is not None:
            return self.reply_override
        return answer(request, self.values, checksum=self.checksum, mode=self.mode)

    def _serve(self) -> None:
        received = b""
        while True:
            ready, _, _ = select.select([self._master, self._stop_r], [], [])
            if self._stop_r in ready:
                return
            try:
                received += os.read(self._master, 4096)
            except OSError:
                return
            *lines, received = received.split(b"\r\n")
            for line in lines:
                reply = self.reply_for(line.decode("ascii", errors="replace"))
                if reply:
                    os.write(self._master, reply)
