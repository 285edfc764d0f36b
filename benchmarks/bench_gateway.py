"""Per-tick I/O latency of the Profibus gateway driver against the simulated gateway, on CAN and Modbus TCP.

Each tick the loop reads its signals and writes its offsets, status word and
heartbeat through a :class:`compd.service.loop.links.DriverLink` (timeouts included). This
times ``--ticks`` such ticks of the benchmark model's size: 7 signals in the
DP input area (5 int16 in 0.01 degC, 2 float32) and 3 int32 offsets in
0.1 um plus status and heartbeat in the output area, with the gateway's
status byte checked and compd's live bit toggled on every write.

- CAN (virtual bus), CANopen PDOs cyclic every 10 ms: a read takes the
  latest frames (no wait), a write sends 3 RPDOs. The gateway runs on its own
  event loop in a thread (a virtual bus does not cross processes).
- CAN (virtual bus), ``sync: true``: each read sends a SYNC and waits for
  that cycle's 4 TPDOs: one bus round trip per tick.
- Modbus TCP: one read of the input area, one write of the output area,
  against the simulated gateway in its own process.
- Beside them, the plain Modbus TCP driver's figure from ``bench_modbus.py``
  (the same tick as separate registers) for comparison.

A real CAN bus adds the frames' time on the wire: at 500 kbit/s about
0.25 ms per 8-byte frame (printed beside the sync figure).

Also the simulated gateway's own ``publish`` of the 7 input values, which
runs every simulated second (at ``--time-scale max`` thousands of times a
real second): us per call, best of 5 runs of 2000 calls.

Targets (issue 5): every driver p99 < 20 ms; Modbus TCP alone < 5 ms;
publish < 50 us.
Run: ``PYTHONPATH=. python benchmarks/bench_gateway.py [--ticks N]``.
"""

from __future__ import annotations

import argparse
import asyncio
import multiprocessing
import os
import sys
import threading
import time
import uuid
from multiprocessing.synchronize import Event
from pathlib import Path
from typing import Any

import bench_modbus
from common import environment, verdict

from compd.drivers.gateway.driver import GatewayDriver, GatewaySettings
from compd.drivers.modbus.settings import ModbusSettings
from compd.service.loop.clock import RealClock
from compd.service.loop.links import DriverLink
from compd.sim.plc.gateway import GatewayServer

MAX_P99_MS = 20.0
MAX_PUBLISH_US = 50.0
READS = [*(f"in:{2 * i}:int16" for i in range(5)), "in:12:float32", "in:16:float32"]
WRITES = {
    "out:0:int32": 0.0,
    "out:4:int32": 0.0,
    "out:8:int32": 0.0,
    "out:12:uint16": 0.0,  # status word
    "out:14:uint16": 0.0,  # heartbeat
}
COMMON: dict[str, Any] = {
    "input_bytes": 32,
    "output_bytes": 24,
    "status": {"offset": 31, "live_bit": 0, "ok_bit": 1},
    "output_live": {"offset": 16, "bit": 0},
    "request_timeout_s": 0.5,
}
#: Frames per sync tick on the wire: SYNC (0 bytes) + 4 TPDOs + 3 RPDOs, ~125 bits each at 8 bytes.
CAN_WIRE_MS_500K = (47 + 7 * 125) / 500_000 * 1e3


def gateway(settings: GatewaySettings) -> GatewayServer:
    server = GatewayServer(
        settings, inputs=READS, outputs=list(WRITES), on_write=lambda a, v: None, base_dir=Path()
    )
    server.publish({a: 2000.0 if "int16" in a else 21.5 for a in READS})
    return server


def serve_modbus(port: int, ready: Event) -> None:
    """Run the simulated gateway over Modbus TCP (in a child process) until killed."""

    async def main() -> None:
        await gateway(GatewaySettings(host="127.0.0.1", port=port, **COMMON)).start()
        ready.set()
        await asyncio.Event().wait()

    asyncio.run(main())


async def ticks(settings: GatewaySettings, n_ticks: int) -> list[float]:
    """Per-tick read + write latency in ms through a DriverLink."""
    driver = GatewayDriver(settings, now=time.monotonic, base_dir=Path())
    link = DriverLink("dp", driver, RealClock(), timeout_s=0.5)
    await link.open()
    assert link.up, "could not connect to the simulated gateway"
    latency_ms = []
    for tick in range(n_ticks + 20):
        values = dict(WRITES, **{"out:14:uint16": float(tick % 65536)})
        start = time.perf_counter()
        read = await link.read(READS)
        wrote = await link.write(values)
        elapsed = time.perf_counter() - start
        assert len(read) == len(READS) and wrote, "a tick's I/O failed"
        if tick >= 20:
            latency_ms.append(elapsed * 1e3)
        await asyncio.sleep(
            0.001
        )  # let the gateway's cycle run between ticks, as in 1 s of service
    await link.close()
    return latency_ms


def publish_us() -> float:
    """us per ``publish`` of the input values, best of 5 runs of 2000 calls (no server started)."""
    server = gateway(GatewaySettings(host="127.0.0.1", port=502, **COMMON))
    values = {a: 2000.0 if "int16" in a else 21.5 for a in READS}
    runs = []
    for _ in range(5):
        start = time.perf_counter()
        for i in range(2000):
            values[READS[0]] = float(i % 1000)
            server.publish(values)
        runs.append((time.perf_counter() - start) / 2000 * 1e6)
    return min(runs)


def run_can(n_ticks: int, **changes: Any) -> list[float]:
    settings = GatewaySettings(
        transport="can",
        interface="virtual",
        channel=f"bench-{uuid.uuid4().hex[:8]}",
        node_id=5,
        byte_order="little",
        word_order="little",
        **COMMON,
        **changes,
    )
    server = gateway(settings)
    loop = asyncio.new_event_loop()
    thread = threading.Thread(target=loop.run_forever, daemon=True)
    thread.start()
    asyncio.run_coroutine_threadsafe(server.start(), loop).result(5)
    try:
        return asyncio.run(ticks(settings, n_ticks))
    finally:
        asyncio.run_coroutine_threadsafe(server.stop(), loop).result(5)
        loop.call_soon_threadsafe(loop.stop)
        thread.join(5)


def run_modbus(n_ticks: int) -> list[float]:
    port = bench_modbus.free_port()
    context = multiprocessing.get_context("spawn")
    ready = context.Event()
    server = context.Process(target=serve_modbus, args=(port, ready), daemon=True)
    server.start()
    try:
        assert ready.wait(20), "the simulated gateway did not start"
        settings = GatewaySettings(host="127.0.0.1", port=port, **COMMON)
        return asyncio.run(ticks(settings, n_ticks))
    finally:
        server.kill()
        server.join()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ticks", type=int, default=2000, help="ticks per case (default 2000)")
    args = parser.parse_args()
    print(
        f"bench_gateway: {args.ticks} ticks, each a read of {len(READS)} signals + a write of "
        f"{len(WRITES)} values (status byte checked, live bit toggled); {environment()}, "
        f"load average {os.getloadavg()[0]:.1f}"
    )
    cost_us = publish_us()
    ok = cost_us < MAX_PUBLISH_US
    print(
        f"{'publish':<10} {cost_us:.1f} us per call of the simulated gateway (best of 5 x 2000)   "
        f"target < {MAX_PUBLISH_US:g} us  {verdict(ok)}"
    )
    report = bench_modbus.report
    ok = report("CAN cyclic", run_can(args.ticks), MAX_P99_MS) and ok
    wire = f"   (a 500 kbit/s bus adds ~{CAN_WIRE_MS_500K:.1f} ms of frames)"
    ok = report("CAN sync", run_can(args.ticks, sync=True), MAX_P99_MS, wire) and ok
    ok = report("Modbus gw", run_modbus(args.ticks), MAX_P99_MS) and ok
    port = bench_modbus.free_port()
    plain = bench_modbus.run(
        "tcp", str(port), ModbusSettings(host="127.0.0.1", port=port), args.ticks
    )
    report("Modbus TCP", plain, bench_modbus.MAX_P99_TCP_MS, "   (plain driver, bench_modbus)")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
