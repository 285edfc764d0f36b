"""A fleet of real daemons into one broker: N ``compd run`` processes, one mosquitto, one subscriber.

``bench_telemetry.py`` part 2 measures 50 publishers in one process: the
broker's and paho's share of the latency. This measures what a shop runs:
``--daemons`` separate ``compd run`` processes (each the bundled simulated
machine on its own port, in real time, a status every tick at QoS 1), all
publishing into one local mosquitto this script starts, for ``--seconds``.
One subscriber keeps every status: lost = the ticks each daemon counted
(its statuses' ``counters.ticks``) that never arrived; latency = the
subscriber's receipt minus the status's time stamp (the tick's wall time),
p50/p99/max over all statuses after every daemon's first. On one host the
daemons, the broker and the subscriber share the CPU, so the latency is
mostly the host's load: give it the machine alone, and say what else ran.

Run: ``PYTHONPATH=. python benchmarks/bench_fleet_daemons.py [--daemons N] [--seconds S]``
(default 50 daemons, 60 s). Needs mosquitto (``.ci/install-system-packages``).
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import environment, verdict

from tests.mosquitto import Mosquitto, Subscriber, machine_config

MAX_P99_MS = 50.0


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--daemons", type=int, default=50, help="compd run processes (default 50)")
    parser.add_argument("--seconds", type=float, default=60.0, help="each one's run (default 60)")
    args = parser.parse_args()
    print(f"bench_fleet_daemons: {environment()}")
    with tempfile.TemporaryDirectory(prefix="compd-bench-fleet-", dir="/tmp") as tmp:
        folder = Path(tmp)
        (folder / "broker").mkdir()
        broker = Mosquitto(folder / "broker").start()
        processes: list[subprocess.Popen[bytes]] = []
        try:
            with Subscriber(broker.port, "fleet/+/status") as sub:
                for k in range(args.daemons):
                    telemetry = {"machine_id": f"m{k:03d}", "host": "127.0.0.1"}
                    telemetry |= {"port": broker.port, "topic_prefix": "fleet"}
                    simulation = {"scenario": "production", "hours": 8, "seed": k}
                    config = machine_config(
                        folder / f"m{k:03d}", telemetry=telemetry, simulation=simulation
                    )
                    command = [sys.executable, "-m", "compd.cli", "run", "--config"]
                    command += [str(config.path), "--duration-s", f"{args.seconds:g}"]
                    command += ["--time-scale", "1"]
                    log = (folder / f"m{k:03d}.log").open("wb")
                    processes.append(
                        subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT)
                    )
                codes = [p.wait() for p in processes]
                time.sleep(2.0)  # the last statuses on their way
                heard = list(sub.messages)
        finally:
            for p in processes:
                if p.poll() is None:
                    p.kill()
            broker.stop()
    by_machine: dict[str, list[tuple[int, float]]] = {}
    for h in heard:
        latency_ms = (h.received_unix_s - h.payload["time"]) * 1e3
        by_machine.setdefault(h.payload["machine_id"], []).append(
            (h.payload["counters"]["ticks"], latency_ms)
        )
    received = sum(len(v) for v in by_machine.values())
    counted = sum(max(t for t, _ in v) - min(t for t, _ in v) + 1 for v in by_machine.values())
    lost = counted - received
    latencies = [ms for v in by_machine.values() for t, ms in v if t > min(t for t, _ in v)]
    failed = sum(code != 0 for code in codes)
    print(f"{args.daemons} compd run processes, {args.seconds:g} s each, a status every tick")
    print(f"   exited non-zero {failed}; machines heard {len(by_machine)}")
    print(f"   statuses counted {counted}, received {received}, lost {lost}  {verdict(lost == 0)}")
    if latencies:
        p50, p99 = statistics.median(latencies), percentile(latencies, 0.99)
        print(
            f"   end-to-end latency p50 {p50:.2f} ms  p99 {p99:.2f} ms  "
            f"max {max(latencies):.2f} ms   target p99 < {MAX_P99_MS:g} ms  "
            f"{verdict(p99 < MAX_P99_MS)}"
        )
    return 0 if lost == 0 and failed == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
