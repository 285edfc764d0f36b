"""Prometheus against a flood of half-open HTTP connections: /metrics latency p50/p99/max and failures.

Issue 33 item 8: with 1,100 clients that connect and send nothing, or send
half a request and stop, against a daemon at ``ulimit -n 256``, ``/metrics``
timed out (15 s) on 3 of 3 tries over 50 s: the server held 64 connections
for the 10 s idle timeout each while the kernel's accept queue held the
rest, first come, first served. This runs that attack on the real daemon:

- ``compd run`` (the config of :mod:`bench_tick`: simulated driver, the
  benchmark model, recorder, state saves, ``http`` with its defaults: 64
  connections, 10 s idle timeout) in a child process whose open-files limit
  is ``--fd-limit`` (``resource.setrlimit`` in the child);
- a flooder in another process that keeps ``--clients`` connections open,
  half silent, half with a request whose headers never end; one the server
  closes is opened again at once, so the accept queue stays full (the worst
  case: an attacker that reconnects);
- in this process, a scraper that fetches ``/metrics`` back to back
  (``--pause-s`` apart) for ``--seconds``, each with Prometheus's default
  timeout of 15 s; a fetch that times out or fails counts as a failure.

Printed per run: the scrapes' latency p50/p99/max and failures, the daemon's
open descriptors (most seen), the connections the flooder had to open again
(the server's turnover), and the daemon's tick lateness p99 (the histogram
bucket that holds it) and overruns, read from the last scrape. With
``--baseline REV`` the same run is made first with the daemon of git
revision ``REV`` (``git archive`` into a temporary directory), side by side;
without it the issue's figure stands as the baseline.

Target: p99 scrape latency < 1 s, no failure.
Run: ``PYTHONPATH=. python benchmarks/bench_http_flood.py [--seconds 40] [--baseline REV]``.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import re
import resource
import signal
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
import urllib.request
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import yaml
from bench_tick import write_config
from common import environment, verdict

ROOT = Path(__file__).resolve().parents[1]
TARGET_P99_S = 1.0
#: Prometheus's default scrape timeout.
SCRAPE_TIMEOUT_S = 15.0
#: The issue's measurement before the fix: 3 scrapes of 3 timed out (15 s) over 50 s.
ISSUE_BASELINE = "3 of 3 scrapes timed out at 15 s over 50 s (issue 33, before the fix)"

#: The flooder: keeps ``count`` connections open to ``port``, half silent, half with an
#: unfinished request; reopens each one the server closes. Prints "ready" once all are
#: started, and on SIGTERM the number it had to open again.
FLOODER = r"""
import selectors, signal, socket, sys
port, count = int(sys.argv[1]), int(sys.argv[2])
HALF = b"GET /metrics HTTP/1.1\r\nHost: compd\r\n"  # no blank line: never complete
sel = selectors.DefaultSelector()
reopened = 0
stop = False

def on_term(*_):
    global stop
    stop = True

signal.signal(signal.SIGTERM, on_term)

def open_one(k):
    s = socket.socket()
    s.setblocking(False)
    s.connect_ex(("127.0.0.1", port))
    sel.register(s, selectors.EVENT_WRITE if k % 2 else selectors.EVENT_READ, k)

for k in range(count):
    open_one(k)
print("ready", flush=True)
while not stop:
    for key, events in sel.select(0.5):
        s, k = key.fileobj, key.data
        if events & selectors.EVENT_WRITE:
            try:
                s.send(HALF)
            except OSError:
                pass
            sel.modify(s, selectors.EVENT_READ, k)
            continue
        try:
            data = s.recv(4096)
        except BlockingIOError:
            continue
        except OSError:
            data = b""
        if not data:
            sel.unregister(s)
            s.close()
            reopened += 1
            open_one(k)
print(reopened, flush=True)
"""


@dataclass
class Run:
    """One daemon under the flood: each scrape's latency (s, None: failed) and what else was seen."""

    label: str
    latencies_s: list[float | None]
    most_fds: int
    reopened: int
    overruns: str
    #: The tick lateness histogram's bucket holding the 99th percentile (ms), from the last scrape.
    lateness_p99_ms: str


def limit_fds(limit: int) -> None:
    resource.setrlimit(resource.RLIMIT_NOFILE, (limit, limit))


def raise_fds(wanted: int) -> None:
    hard = resource.getrlimit(resource.RLIMIT_NOFILE)[1]
    if hard != resource.RLIM_INFINITY and hard < wanted:
        hard = wanted  # as root; otherwise the flooder opens what it may
    with contextlib.suppress(ValueError, OSError):
        resource.setrlimit(resource.RLIMIT_NOFILE, (wanted, hard))


def free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@contextlib.contextmanager
def source_tree(rev: str | None) -> Iterator[Path]:
    """This checkout, or revision ``rev`` extracted into a temporary directory."""
    if rev is None:
        yield ROOT
        return
    archive = subprocess.run(
        ["git", "-C", str(ROOT), "archive", "--format=tar", rev], check=True, capture_output=True
    ).stdout
    with tempfile.TemporaryDirectory(prefix="compd-bench-flood-src-") as tmp:
        with tarfile.open(fileobj=io.BytesIO(archive)) as tar:
            tar.extractall(tmp, filter="tar")
        yield Path(tmp)


def scrape(url: str) -> tuple[float | None, bytes]:
    start = time.perf_counter()
    try:
        with urllib.request.urlopen(url, timeout=SCRAPE_TIMEOUT_S) as response:
            body = response.read()
            ok = response.status == 200
    except OSError:
        return None, b""
    return (time.perf_counter() - start if ok else None), body


def measure(label: str, tree: Path, args: argparse.Namespace) -> Run:
    with tempfile.TemporaryDirectory(prefix="compd-bench-flood-", dir="/tmp") as tmp:
        path = write_config(Path(tmp), int(args.seconds) + 600)
        port = free_port()
        doc = yaml.safe_load(path.read_text())
        doc["http"] = {"port": port}
        path.write_text(yaml.safe_dump(doc, sort_keys=False))
        env = {**os.environ, "PYTHONPATH": str(tree)}
        daemon = subprocess.Popen(
            [sys.executable, "-m", "compd.cli", "run", "--config", str(path)],
            cwd=tmp,
            env=env,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
            preexec_fn=lambda: limit_fds(args.fd_limit),
        )
        url = f"http://127.0.0.1:{port}/metrics"
        flooder = None
        try:
            deadline = time.monotonic() + 60
            while scrape(url)[0] is None:
                assert daemon.poll() is None, daemon.communicate()[1][-3000:]
                assert time.monotonic() < deadline, "the daemon never answered"
                time.sleep(0.2)
            flooder = subprocess.Popen(
                [sys.executable, "-c", FLOODER, str(port), str(args.clients)],
                stdout=subprocess.PIPE,
                text=True,
                preexec_fn=lambda: raise_fds(args.clients + 64),
            )
            assert flooder.stdout is not None and flooder.stdout.readline().strip() == "ready"
            time.sleep(2.0)  # the queue fills, the slots are taken
            latencies: list[float | None] = []
            most_fds, body = 0, b""
            end = time.monotonic() + args.seconds
            while time.monotonic() < end:
                latency, got = scrape(url)
                latencies.append(latency)
                body = got or body
                most_fds = max(most_fds, len(os.listdir(f"/proc/{daemon.pid}/fd")))
                if args.verbose:
                    took = "failed" if latency is None else f"{latency * 1e3:.1f} ms"
                    print(f"  {label}: scrape {len(latencies)}: {took}", flush=True)
                time.sleep(args.pause_s)
            flooder.send_signal(signal.SIGTERM)
            reopened = int(flooder.communicate(timeout=30)[0].strip() or 0)
        finally:
            if flooder is not None and flooder.poll() is None:
                flooder.kill()
                flooder.wait()
            daemon.send_signal(signal.SIGTERM)
            try:
                daemon.communicate(timeout=60)
            except subprocess.TimeoutExpired:
                daemon.kill()
                daemon.communicate()
        found = re.search(rb"^compd_overruns_total (\S+)$", body, re.M)
        overruns = "?" if found is None else str(int(float(found.group(1))))
        return Run(label, latencies, most_fds, reopened, overruns, lateness_p99(body))


def lateness_p99(body: bytes) -> str:
    """``<= X`` ms: the upper bound of the lateness histogram's bucket that holds the 99th percentile."""
    pattern = rb'^compd_tick_lateness_seconds_bucket\{le="([^"]+)"\} (\S+)$'
    buckets = [(float(le), float(n)) for le, n in re.findall(pattern, body, re.M)]
    if not buckets:
        return "?"
    total = buckets[-1][1]
    bound = next(le for le, n in buckets if n >= 0.99 * total)
    return f"<= {bound * 1e3:g} ms"


def quantile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


def report(run: Run, seconds: float) -> bool:
    """Print one run's line; whether it meets the target (a failed scrape counts as past it)."""
    served = [s for s in run.latencies_s if s is not None]
    failed = len(run.latencies_s) - len(served)
    # A failed scrape took at least the timeout: p99 and max count it as that.
    waited = served + [SCRAPE_TIMEOUT_S] * failed
    p50, p99, most = (
        (statistics.median(waited), quantile(waited, 0.99), max(waited)) if waited else (0, 0, 0)
    )
    print(
        f"{run.label:<9} scrapes {len(run.latencies_s):>4} over {seconds:g} s  "
        f"failed {failed:>3}  p50 {p50 * 1e3:8.1f} ms  p99 {p99 * 1e3:8.1f} ms  "
        f"max {most * 1e3:8.1f} ms  daemon fds <= {run.most_fds}  "
        f"reconnects {run.reopened}  tick lateness p99 {run.lateness_p99_ms}  "
        f"overruns {run.overruns}"
    )
    return failed == 0 and bool(served) and p99 < TARGET_P99_S


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=40.0, help="scraping under the flood")
    parser.add_argument("--clients", type=int, default=1100, help="half-open connections")
    parser.add_argument("--fd-limit", type=int, default=256, help="the daemon's ulimit -n")
    parser.add_argument("--pause-s", type=float, default=0.2, help="between scrapes")
    parser.add_argument(
        "--baseline", metavar="REV", help="also run the daemon of git revision REV, first"
    )
    parser.add_argument("--verbose", action="store_true", help="print every scrape")
    args = parser.parse_args()
    print(
        f"bench_http_flood: {args.clients} half-open clients (reconnecting), daemon at "
        f"ulimit -n {args.fd_limit}, /metrics back to back for {args.seconds:g} s "
        f"(timeout {SCRAPE_TIMEOUT_S:g} s); {environment()}"
    )
    if args.baseline is not None:
        with source_tree(args.baseline) as tree:
            report(measure(f"baseline ({args.baseline})", tree, args), args.seconds)
    else:
        print(f"baseline  {ISSUE_BASELINE}")
    ok = report(measure("compd", ROOT, args), args.seconds)
    print(f"p99 scrape latency < {TARGET_P99_S:g} s, none failed: {verdict(ok)}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
