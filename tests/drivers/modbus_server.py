"""Real Modbus counterparts for the driver tests: a pymodbus server in a thread, and a TCP relay to cut.

The server's device has coils 0-15, discrete inputs 0-15, holding registers
0-149 (plus 150-159 read-only, so writes there are refused) and input
registers 0-15 preset with :data:`INPUTS`, encoded by compd's own codec.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import threading
from collections.abc import Callable, Iterator
from typing import Any

from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from compd.drivers.modbus.addresses import parse_address
from tests.ports import free_port as free_port  # re-exported: tests import it from here

# Input registers preset with values in several layouts (addresses 0-based).
INPUTS = {
    "input:0:int16": -1234,  # e.g. -12.34 degC at scale 0.01
    "input:1:uint16": 60000,
    "input:2:float32:word=little": 21.5,
    "input:4:uint32": 3_000_000_000,
    "input:6:float64:byte=little:word=little": -0.125,
}
# A machine's signals for service tests: int16 in 0.01 degC, speed in rpm.
MACHINE = {"input:10:int16": 2500, "input:11:int16": 2200, "input:12:uint16": 3000}
READONLY_START = 150  # holding 150..159 are read-only: writes are refused


def _input_registers() -> list[int]:
    registers = [0] * 16
    for address, value in {**INPUTS, **MACHINE}.items():
        point = parse_address(address)
        words = point.codec.encode_registers(value)
        registers[point.address : point.address + len(words)] = words
    return registers


def make_device() -> SimDevice:
    """Coils 0-15, discrete inputs 0-15, holding 0-149 (+150-159 read-only), inputs 0-15."""
    return SimDevice(
        id=1,
        simdata=(
            [SimData(0, count=16, values=False, datatype=DataType.BITS)],
            [SimData(0, values=[True, False, True] + [False] * 13, datatype=DataType.BITS)],
            [
                SimData(0, count=READONLY_START, values=0, datatype=DataType.REGISTERS),
                SimData(
                    READONLY_START, count=10, values=7, datatype=DataType.REGISTERS, readonly=True
                ),
            ],
            [SimData(0, values=_input_registers(), datatype=DataType.REGISTERS)],
        ),
    )


class ServerThread:
    """A pymodbus server running on its own event loop in a thread; stop() and start() again."""

    def __init__(self, make_server: Callable[[], Any]) -> None:
        self._make_server = make_server
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._stopping: asyncio.Event | None = None

    def start(self) -> None:
        ready = threading.Event()

        def run() -> None:
            async def main() -> None:
                self._stopping = asyncio.Event()
                self._loop = asyncio.get_running_loop()
                server = self._make_server()  # pymodbus binds to the running loop
                await server.serve_forever(background=True)
                ready.set()
                await self._stopping.wait()
                await server.shutdown()

            asyncio.run(main())

        self._thread = threading.Thread(target=run, daemon=True)
        self._thread.start()
        assert ready.wait(60), "server did not start"  # a hang guard

    def stop(self) -> None:
        if self._loop is not None and self._thread is not None:
            self._loop.call_soon_threadsafe(self._stopping.set)
            self._thread.join(5)
            self._loop = self._thread = None


def tcp_server(port: int) -> ServerThread:
    return ServerThread(lambda: ModbusTcpServer(make_device(), address=("127.0.0.1", port)))


@contextlib.contextmanager
def running_tcp_server() -> Iterator[int]:
    """A pymodbus server on 127.0.0.1 (:func:`make_device`) for the ``with`` block: its port."""
    port = free_port()
    server = tcp_server(port)
    server.start()
    try:
        yield port
    finally:
        server.stop()


class TcpProxy:
    """A byte-for-byte TCP relay to 127.0.0.1:``target`` whose cut() drops every connection and stops listening."""

    def __init__(self, target: int) -> None:
        self._listener = socket.create_server(("127.0.0.1", 0))
        self.port = int(self._listener.getsockname()[1])
        self._target = target
        self._sockets: list[socket.socket] = []
        self._lock = threading.Lock()
        self._cut = False
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        while True:
            try:
                client, _ = self._listener.accept()
            except OSError:
                return
            try:
                upstream = socket.create_connection(("127.0.0.1", self._target))
            except (
                OSError
            ):  # the server behind is gone (stopped at the test's end): drop the client
                client.close()
                continue
            with self._lock:
                if self._cut:  # accepted while cut() ran: refuse it too
                    client.close()
                    upstream.close()
                    return
                self._sockets += [client, upstream]
            for a, b in ((client, upstream), (upstream, client)):
                threading.Thread(target=self._pipe, args=(a, b), daemon=True).start()

    @staticmethod
    def _pipe(source: socket.socket, sink: socket.socket) -> None:
        try:
            while data := source.recv(65536):
                sink.sendall(data)
        except OSError:
            pass
        for s in (source, sink):
            with contextlib.suppress(OSError):
                s.shutdown(socket.SHUT_RDWR)

    def cut(self) -> None:
        self._listener.close()
        with self._lock:
            self._cut = True
            for s in self._sockets:
                with contextlib.suppress(OSError):
                    s.shutdown(socket.SHUT_RDWR)
                s.close()
