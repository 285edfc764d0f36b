"""Shared set-up for the Profibus gateway tests: settings, a published image, a gateway in a thread.

The simulated gateway (:class:`compd.sim.plc.gateway.GatewayServer`) is
asyncio-native; tests that drive it from their own loop start it there,
while the contract suite (whose tests each run their own ``asyncio.run``)
gets it in a thread with a loop of its own, as a gateway is its own device.
"""

from __future__ import annotations

import asyncio
import threading
import uuid
from collections.abc import Callable, Coroutine
from pathlib import Path
from typing import Any

from compd.drivers.gateway.driver import GatewayDriver, GatewaySettings
from compd.sim.plc.gateway import GatewayServer

#: Raw values the gateway publishes: every type, both orders, bytes and bits, all inside one 8-byte frame each.
INPUTS: dict[str, float] = {
    "in:0:int16": -1234.0,
    "in:2:uint16": 60000.0,
    "in:4:float32:word=big:byte=big": 21.5,
    "in:8:int32": -123456789.0,
    "in:12:uint8": 200.0,
    "in:13:int8": -5.0,
    "in:14.2": 1.0,
    "in:16:float64": -0.125,
}
OUTPUTS = ("out:0:int32", "out:4:int16", "out:6.0", "out:8:float32")
#: Status byte in the last input byte; bit 0 live, bit 1 ok. compd's live bit: out:7.7.
STATUS = {"offset": 31, "live_bit": 0, "ok_bit": 1}
OUTPUT_LIVE = {"offset": 7, "bit": 7}


def channel_name() -> str:
    """A virtual CAN channel no other test uses."""
    return f"gw-{uuid.uuid4().hex[:12]}"


def can_settings(channel: str, **changes: Any) -> GatewaySettings:
    """A CANopen gateway (node 5) on a virtual bus: 32 bytes each way, little-endian like CANopen."""
    options: dict[str, Any] = {
        "transport": "can",
        "interface": "virtual",
        "channel": channel,
        "node_id": 5,
        "input_bytes": 32,
        "output_bytes": 16,
        "byte_order": "little",
        "word_order": "little",
        # Generous for a loaded CI machine; tests of the timeouts set their own.
        "stale_s": 0.5,
        "frame_timeout_s": 1.0,
        "request_timeout_s": 0.5,
        "status": STATUS,
        "live_timeout_s": 0.5,
        "output_live": OUTPUT_LIVE,
    }
    options.update(changes)
    return GatewaySettings.model_validate(options)


def modbus_settings(port: int, **changes: Any) -> GatewaySettings:
    """A Modbus TCP gateway (Anybus-like): inputs from input register 10, outputs from holding 100."""
    options: dict[str, Any] = {
        "transport": "modbus_tcp",
        "host": "127.0.0.1",
        "port": port,
        "input_register": 10,
        "output_register": 100,
        "input_bytes": 32,
        "output_bytes": 16,
        # A read on a loaded 2-core machine has missed 0.5 s (the contract's float read, once in
        # a full suite run beside other jobs); tests of the timeouts set their own.
        "request_timeout_s": 2.0,
        "status": STATUS,
        "live_timeout_s": 0.5,
        "output_live": OUTPUT_LIVE,
    }
    options.update(changes)
    return GatewaySettings.model_validate(options)


def make_driver(settings: GatewaySettings) -> GatewayDriver:
    return GatewayDriver(settings, now=lambda: 0.0, base_dir=Path())


def make_server(
    settings: GatewaySettings, written: list[tuple[str, float]] | None = None, **options: Any
) -> GatewayServer:
    """A gateway serving :data:`INPUTS` (published) and taking :data:`OUTPUTS`."""
    sink = written if written is not None else []
    server = GatewayServer(
        settings,
        inputs=list(INPUTS),
        outputs=list(OUTPUTS),
        on_write=lambda address, raw: sink.append((address, raw)),
        base_dir=Path(),
        **options,
    )
    server.publish(INPUTS)
    return server


class ThreadedGateway:
    """A :class:`GatewayServer` running on its own event loop in a thread."""

    def __init__(self, server: GatewayServer) -> None:
        self.server = server
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, daemon=True)
        self._thread.start()

    def call(self, make: Callable[[], Coroutine[Any, Any, Any]]) -> Any:
        return asyncio.run_coroutine_threadsafe(make(), self._loop).result(5)

    def start(self) -> None:
        self.call(self.server.start)

    def stop(self) -> None:
        self.call(self.server.stop)

    def close(self) -> None:
        self.stop()
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(5)
        self._loop.close()
