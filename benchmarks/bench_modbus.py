"""Per-tick I/O latency of the Modbus driver against a local pymodbus server (TCP, and RTU on a pty).

Each tick the loop reads its signals and writes its offsets, status word and
heartbeat through a :class:`compd.service.loop.links.DriverLink` (timeouts included). This
times ``--ticks`` such ticks of the benchmark model's size: 7 signals in PLC
input registers (5 int16 in 0.01 degC, 2 float32 word-swapped: one merged
read) and 3 int32 offsets in 0.1 um plus status and heartbeat in holding
registers (one merged write), against a pymodbus server in its own process
(as a PLC is its own device), and reports p50/p99/max in ms.

With ``socat`` installed (``.ci/install-system-packages``) it also times
Modbus RTU over a pty pair. A pty moves bytes at memory speed; on a real line
each exchange adds ``bytes * 10 / baud`` seconds (8N1), printed beside it.

Targets (issue 5): Modbus TCP p99 < 5 ms; every driver p99 < 20 ms.
Run: ``PYTHONPATH=. python benchmarks/bench_modbus.py [--ticks N]``.
"""

from __future__ import annotations

import argparse
import asyncio
import multiprocessing
import os
import shutil
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from multiprocessing.synchronize import Event
from pathlib import Path

from common import environment, verdict

from compd.drivers.modbus.driver import ModbusDriver
from compd.drivers.modbus.settings import ModbusSettings
from compd.service.loop.clock import RealClock
from compd.service.loop.links import DriverLink

MAX_P99_TCP_MS = 5.0
MAX_P99_ANY_MS = 20.0
READS = [f"input:{i}:int16" for i in range(5)] + [
    "input:5:float32:word=little",
    "input:7:float32:word=little",
]
WRITES = {
    "holding:0:int32": 0.0,
    "holding:2:int32": 0.0,
    "holding:4:int32": 0.0,
    "holding:6": 0.0,
    "holding:7": 0.0,
}
# Bytes on the wire per tick in RTU: read 9 registers (8 + 5 + 2*9), write 8 (9 + 2*8 + 8).
RTU_BYTES_PER_TICK = 8 + (5 + 2 * 9) + (9 + 2 * 8) + 8


def serve(transport: str, where: str, ready: Event) -> None:
    """Run a pymodbus server (in a child process) until killed."""
    from pymodbus.server import ModbusSerialServer, ModbusTcpServer
    from pymodbus.simulator import DataType, SimData, SimDevice

    device = SimDevice(
        id=1,
        simdata=(
            [SimData(0, count=16, values=False, datatype=DataType.BITS)],
            [SimData(0, count=16, values=False, datatype=DataType.BITS)],
            [SimData(0, count=100, values=0, datatype=DataType.REGISTERS)],
            [SimData(0, count=100, values=2000, datatype=DataType.REGISTERS)],
        ),
    )

    async def main() -> None:
        if transport == "tcp":
            server = ModbusTcpServer(device, address=("127.0.0.1", int(where)))
        else:
            server = ModbusSerialServer(device, port=where, baudrate=115200)
        await server.serve_forever(background=True)
        ready.set()
        await asyncio.Event().wait()

    asyncio.run(main())


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


async def ticks(settings: ModbusSettings, n_ticks: int) -> list[float]:
    """Per-tick read + write latency in ms through a DriverLink."""
    driver = ModbusDriver(settings, now=time.monotonic, base_dir=Path())
    link = DriverLink("plc", driver, RealClock(), timeout_s=0.5)
    await link.open()
    assert link.up, "could not connect to the benchmark server"
    latency_ms = []
    for tick in range(n_ticks + 20):
        values = dict(WRITES, **{"holding:7": float(tick % 32768)})
        start = time.perf_counter()
        read = await link.read(READS)
        wrote = await link.write(values)
        elapsed = time.perf_counter() - start
        assert len(read) == len(READS) and wrote, "a tick's I/O failed"
        if tick >= 20:  # the first ticks warm up caches and the server's loop
            latency_ms.append(elapsed * 1e3)
    await link.close()
    return latency_ms


def run(transport: str, where: str, settings: ModbusSettings, n_ticks: int) -> list[float]:
    context = multiprocessing.get_context("spawn")
    ready = context.Event()
    server = context.Process(target=serve, args=(transport, where, ready), daemon=True)
    server.start()
    try:
        assert ready.wait(20), "the benchmark server did not start"
        return asyncio.run(ticks(settings, n_ticks))
    finally:
        server.kill()
        server.join()


def report(name: str, latency_ms: list[float], target_ms: float, extra: str = "") -> bool:
    ordered = sorted(latency_ms)
    p99 = ordered[min(len(ordered) - 1, int(0.99 * len(ordered)))]
    ok = p99 < target_ms
    print(
        f"{name:<10} p50 {statistics.median(ordered):.3f} ms  p99 {p99:.3f} ms  "
        f"max {ordered[-1]:.3f} ms   target p99 < {target_ms:g} ms  {verdict(ok)}{extra}"
    )
    return ok


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--ticks", type=int, default=2000, help="ticks per transport (default 2000)"
    )
    args = parser.parse_args()
    print(
        f"bench_modbus: {args.ticks} ticks, each a read of {len(READS)} signals (1 request) "
        f"+ a write of {len(WRITES)} values (1 request); {environment()}, "
        f"load average {os.getloadavg()[0]:.1f}"
    )
    port = free_port()
    tcp = run("tcp", str(port), ModbusSettings(host="127.0.0.1", port=port), args.ticks)
    ok = report("TCP", tcp, MAX_P99_TCP_MS)
    if shutil.which("socat") is None:
        print("RTU        skipped: socat not installed (.ci/install-system-packages)")
        return 0 if ok else 1
    with tempfile.TemporaryDirectory(prefix="compd-bench-") as tmp:
        ours, theirs = Path(tmp) / "compd-tty", Path(tmp) / "plc-tty"
        socat = subprocess.Popen(
            ["socat", f"pty,raw,echo=0,link={ours}", f"pty,raw,echo=0,link={theirs}"],
            stderr=subprocess.DEVNULL,
        )
        try:
            while not (ours.exists() and theirs.exists()):
                time.sleep(0.02)
            settings = ModbusSettings(transport="rtu", serial_port=str(ours), baudrate=115200)
            rtu = run("rtu", str(theirs), settings, args.ticks)
        finally:
            socat.terminate()
            socat.wait()
    wire = ", ".join(
        f"{baud}: +{RTU_BYTES_PER_TICK * 10 / baud * 1e3:.1f} ms" for baud in (19200, 115200)
    )
    ok = report("RTU (pty)", rtu, MAX_P99_ANY_MS, f"   (real line adds {wire})") and ok
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
