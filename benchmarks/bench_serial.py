"""Per-tick I/O latency of the serial-sensor driver against a simulated scanner on a pseudo-terminal.

Each tick the loop reads every scanner channel through its
:class:`compd.service.loop.links.DriverLink` (timeout included); a scanner is read-only, so
a tick's I/O is that read alone. This times ``--ticks`` such reads of 8
channels against the test suite's :class:`tests.drivers.instrument.PtyInstrument`
(in its own process, as a real scanner is its own device; XOR checksums both
ways) and reports p50/p99/max in ms, for one request per tick
(``{channels}``), for one request per channel (``{channel}``) and with
``poll: background`` (the read returns what the poller last fetched).

A pty moves bytes at memory speed; a real line does not. The time the bytes
of one exchange spend on the wire is added by the physics, not the driver::

    wire_ms = (request bytes + reply bytes) * (1 start + data + parity + stop bits) / baud * 1e3

and is printed beside the measured figure for common baud rates.

Target (issue 5): one tick's I/O p99 < 20 ms for every driver.
Run: ``PYTHONPATH=. python benchmarks/bench_serial.py [--ticks N]``.
"""

from __future__ import annotations

import argparse
import asyncio
import multiprocessing
import statistics
import sys
import tempfile
import time
from multiprocessing.synchronize import Event
from pathlib import Path

from common import environment, verdict

from compd.drivers.serial_sensor import SerialSensorDriver, SerialSensorSettings
from compd.service.loop.clock import RealClock
from compd.service.loop.links import DriverLink
from tests.drivers.instrument import PtyInstrument, answer, xor_hex

MAX_P99_MS = 20.0
CHANNELS = [str(i) for i in range(1, 9)]
VALUES = {c: 20.0 + 0.123 * i for i, c in enumerate(CHANNELS)}
BAUD_RATES = (9600, 115200)
WARMUP_TICKS = 50
#: Background mode: the poller's period in this benchmark (s); ticks come every 2 periods.
BACKGROUND_PERIOD_S = 0.005


def measure(port: Path, request: str, n_ticks: int, *, background: bool = False) -> list[float]:
    """Read all channels ``n_ticks`` times through a DriverLink; returns each read's latency (ms).

    ``background``: the driver polls every ``BACKGROUND_PERIOD_S`` on its own and the
    ticks come every ``2 * BACKGROUND_PERIOD_S``, so each read finds a completed poll.
    """
    settings = SerialSensorSettings(
        port=str(port),
        request=request,
        checksum="xor",
        request_checksum=True,
        channels=tuple(CHANNELS),
        poll="background" if background else "on_read",
        poll_period_s=BACKGROUND_PERIOD_S,
    )
    driver = SerialSensorDriver(settings, now=time.monotonic, base_dir=port.parent)
    link = DriverLink("scanner", driver, RealClock(), timeout_s=0.5)

    async def run() -> list[float]:
        await link.open()
        latencies_ms = []
        for tick in range(WARMUP_TICKS + n_ticks):
            if background:
                await asyncio.sleep(2 * BACKGROUND_PERIOD_S)
            start = time.perf_counter()
            values = await link.read(CHANNELS)
            elapsed_ms = (time.perf_counter() - start) * 1e3
            if len(values) != len(CHANNELS):
                raise RuntimeError(f"tick {tick}: read {values}, link up={link.up}")
            if tick >= WARMUP_TICKS:
                latencies_ms.append(elapsed_ms)
        await link.close()
        return latencies_ms

    return asyncio.run(run())


def serve(port: Path, ready: Event, stop: Event) -> None:
    """The scanner, in its own process (as a real one is its own device) until ``stop``."""
    instrument = PtyInstrument(port, VALUES, checksum=True)
    ready.set()
    stop.wait()
    instrument.unplug()


def wire_ms(request: str, baud: int) -> float:
    """Time on the wire (ms) of one exchange for ``request`` at ``baud``, 8N1 (10 bits per byte)."""
    channels = ",".join(CHANNELS) if "{channels}" in request else CHANNELS[0]
    line = request.format(channels=channels, channel=channels)
    sent = f"{line}*{xor_hex(line.encode())}\r\n"
    reply = answer(line, VALUES, checksum=False)  # + 3 bytes below: "*HH"
    assert reply is not None
    return (len(sent) + len(reply) + 3) * 10 / baud * 1e3


def report(name: str, latencies_ms: list[float]) -> bool:
    ordered = sorted(latencies_ms)
    p50 = statistics.median(ordered)
    p99 = ordered[min(len(ordered) - 1, int(0.99 * len(ordered)))]
    ok = p99 < MAX_P99_MS
    print(
        f"{name:<26} p50 {p50:.3f} ms  p99 {p99:.3f} ms  max {ordered[-1]:.3f} ms   "
        f"target p99 < {MAX_P99_MS:g} ms  {verdict(ok)}"
    )
    return ok


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ticks", type=int, default=2000, help="reads to time (default 2000)")
    args = parser.parse_args()
    print(f"bench_serial: {args.ticks} ticks of {len(CHANNELS)} channels on a pty; {environment()}")
    ok = True
    with tempfile.TemporaryDirectory(prefix="compd-bench-", dir="/tmp") as tmp:
        port = Path(tmp) / "ttyScanner"
        context = multiprocessing.get_context("fork")  # no threads exist yet in this process
        ready, stop = context.Event(), context.Event()
        child = context.Process(target=serve, args=(port, ready, stop), daemon=True)
        child.start()
        try:
            if not ready.wait(10.0):
                raise RuntimeError("the instrument process did not start")
            for name, request in (
                ("one request per tick", "MEAS? {channels}"),
                ("one request per channel", "MEAS? {channel}"),
            ):
                ok &= report(name, measure(port, request, args.ticks))
                requests = 1 if "{channels}" in request else len(CHANNELS)
                wire = ", ".join(
                    f"{requests * wire_ms(request, b):.1f} ms at {b} baud" for b in BAUD_RATES
                )
                print(f"{'':<26} + time on a real wire per tick (8N1): {wire}")
            n_background = max(1, args.ticks // 4)  # each tick sleeps 10 ms
            ok &= report(
                "background poll", measure(port, "MEAS? {channels}", n_background, background=True)
            )
            print(f"{'':<26} (the read returns the last poll: no wire time in the tick)")
        finally:
            stop.set()
            child.join(10.0)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
