"""What the HTTP server and its metrics cost the 1 Hz tick: lateness p99 and CPU per tick, on beside off.

Runs the real service of :mod:`bench_tick` (simulated driver, the benchmark
model of :mod:`common`, signal checks, safety, writes, recorder, state saves)
on the real clock twice per round -- ``http`` off, then on -- for ``--ticks``
ticks each. While the server is on, a scraper in another process fetches
``/metrics`` every second as Prometheus would (and with ``--page``, what an
open status page fetches too: ``/status.json`` and ``/page.json`` every 2 s,
``/history.json`` every 10 s), so the daemon's figures include answering
them. Reported per run:

- lateness: how long after its deadline each tick started (ms), p50/p99/max;
- CPU per tick: process CPU time from the first tick to the last divided by
  the ticks (ms): the tick, plus the server's answers when it is on.

Also, on their own (best of 3 x 1000, CPU time): what a tick adds with the
server on (:meth:`compd.service.http.server.StatusServer.tick`: two histogram
observations, a history row, the fault check) and what one ``/metrics``
answer costs to build.

Target (issue 16): p99 lateness with metrics on grows by no more than 1 ms
over off. ``--ticks 600`` (the default) is 10 minutes per run at 1 Hz.
Run: ``PYTHONPATH=. python benchmarks/bench_metrics.py [--ticks N] [--rounds R] [--page]``.
"""

from __future__ import annotations

import argparse
import asyncio
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml
from bench_tick import write_config
from common import environment, verdict

from compd.service.config.loading import load_config
from compd.service.daemon import Service
from compd.service.loop.clock import RealClock, VirtualClock
from compd.service.loop.compensator import TickRecord

MAX_P99_GROWTH_MS = 1.0

#: The scraper, in its own process so its CPU is not the daemon's: bounded in count, it stops itself.
SCRAPER = """
import sys, time, urllib.request
url, seconds, page = sys.argv[1], float(sys.argv[2]), sys.argv[3] == "1"
def get(path):
    try:
        with urllib.request.urlopen(url + path, timeout=5) as r:
            r.read()
    except OSError:
        pass
start = time.monotonic()
for k in range(int(seconds)):
    time.sleep(max(0.0, start + k - time.monotonic()))
    get("metrics")
    if page and k % 2 == 0:
        get("status.json"); get("page.json")
    if page and k % 10 == 0:
        get("history.json?points=720")
"""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def config_path(directory: Path, n_ticks: int, *, http: bool) -> tuple[Path, int]:
    """bench_tick's config, with ``http`` on a free loopback port when asked; the path and the port."""
    path = write_config(directory, n_ticks)
    port = free_port()
    if http:
        doc = yaml.safe_load(path.read_text())
        doc["http"] = {"port": port}
        path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path, port


def measure(n_ticks: int, *, http: bool, page: bool) -> tuple[list[float], float, int]:
    """Run the service for ``n_ticks`` at 1 Hz; per-tick lateness (ms), CPU ms per tick, overruns."""
    with tempfile.TemporaryDirectory(prefix="compd-bench-metrics-", dir="/tmp") as tmp:
        path, port = config_path(Path(tmp), n_ticks, http=http)
        service = Service(load_config(path), clock=RealClock())
        lateness_ms: list[float] = []
        cpu_s: list[float] = []

        def on_tick(_: TickRecord) -> None:
            lateness_ms.append(service.timing.last_lateness_s * 1e3)
            cpu_s.append(time.process_time())

        service.subscribe(on_tick)
        scraper = None
        if http:
            url = f"http://127.0.0.1:{port}/"
            args = [sys.executable, "-c", SCRAPER, url, str(n_ticks + 5), "1" if page else "0"]
            scraper = subprocess.Popen(args)
        try:
            asyncio.run(service.run(duration_s=float(n_ticks - 1)))
        finally:
            if scraper is not None:
                scraper.terminate()
                scraper.wait()
        cpu_ms = (cpu_s[-1] - cpu_s[0]) * 1e3 / (len(cpu_s) - 1)
        return lateness_ms, cpu_ms, service.timing.overruns


def micro_costs_us() -> tuple[float, float]:
    """CPU us: what one tick adds with the server on, and one ``/metrics`` answer (best of 3 x 1000)."""
    with tempfile.TemporaryDirectory(prefix="compd-bench-metrics-", dir="/tmp") as tmp:
        path, _ = config_path(Path(tmp), 200, http=True)
        service = Service(load_config(path), clock=VirtualClock(), control=False)
        assert service.http is not None
        asyncio.run(service.run(duration_s=100.0))  # a real last tick to record
        record = service.compensator.last
        assert record is not None
        http, n = service.http, 1000
        tick_runs, render_runs = [], []
        for _ in range(3):
            start = time.process_time()
            for _ in range(n):
                http.tick(record, 0.0001, 0.0005, time.perf_counter())
            tick_runs.append((time.process_time() - start) / n * 1e6)
            start = time.process_time()
            for _ in range(n):
                http.metrics.render()
            render_runs.append((time.process_time() - start) / n * 1e6)
    return min(tick_runs), min(render_runs)


def p99(values: list[float]) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(0.99 * len(ordered)))]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--ticks", type=int, default=600, help="ticks per run, at 1 Hz (default 600)"
    )
    parser.add_argument("--rounds", type=int, default=1, help="off/on pairs (default 1)")
    parser.add_argument(
        "--page", action="store_true", help="also fetch what an open status page does"
    )
    args = parser.parse_args()
    print(f"bench_metrics: {args.rounds} x (off, on) x {args.ticks} ticks at 1 Hz; {environment()}")
    tick_us, render_us = micro_costs_us()
    print(f"server on, per tick: {tick_us:.1f} us CPU (histograms, history row, fault check)")
    print(f"one /metrics answer: {render_us:.0f} us CPU to build")
    p99s: dict[bool, list[float]] = {False: [], True: []}
    for _ in range(args.rounds):
        for http in (False, True):
            lateness, cpu_ms, overruns = measure(args.ticks, http=http, page=args.page)
            p99s[http].append(p99(lateness))
            label = "on " if http else "off"
            scraped = (
                " (/metrics every 1 s" + (" + the page)" if args.page else ")") if http else ""
            )
            print(
                f"http {label}  lateness p50 {statistics.median(lateness):.3f} ms  "
                f"p99 {p99(lateness):.3f} ms  max {max(lateness):.3f} ms  "
                f"CPU/tick {cpu_ms:.3f} ms  overruns {overruns}{scraped}"
            )
    growth = statistics.median(p99s[True]) - statistics.median(p99s[False])
    ok = growth <= MAX_P99_GROWTH_MS
    print(
        f"p99 lateness growth, on - off: {growth:+.3f} ms   "
        f"target <= {MAX_P99_GROWTH_MS:g} ms  {verdict(ok)}"
    )
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
