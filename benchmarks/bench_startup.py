"""Start-up of the commands and the daemon's resident memory: ``compd`` parses first, imports later.

Each command runs in a fresh interpreter, 7 times; the figures are the median
wall time and the median CPU time (user + system) of the process. Beside them:

- the interpreter alone (``python -c pass``): the floor no command can beat;
- every command's parser built eagerly (``build_parser()``), which is what
  each command cost before the command table (issue 13: 3.0-3.4 s, 218 MB).

The daemon: ``compd run`` for 20 s on a config for a real machine (Modbus
TCP, the twin serving it from its own process, as a PLC would), its peak
resident memory (``ru_maxrss``) with the bundled model as shipped (its
difference equations precompiled at the loop's 1 s: the daemon compiles,
checks and steps them with numpy alone); beside ``compd run`` on the
simulated config (the twin, pandas and the scenario inside the same
process), and beside the libraries the daemon needs, imported and nothing
run (the floor). ``benchmarks/bench_daemon_memory.py`` sets the daemon
beside the way it was, converting the model at load with scipy.

This process imports neither numpy nor compd: a child's peak resident
memory counts its parent's pages up to ``exec`` (``ru_maxrss`` survives it),
so a heavy parent would inflate every figure.

Targets: ``--help``, ``--version`` and ``status`` < 0.3 s; the daemon < 60 MB.
Run: ``PYTHONPATH=. python benchmarks/bench_startup.py``.
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # tests.ports (simconfig's too)
from simconfig import simulated_and_real

ROOT = Path(__file__).resolve().parents[1]
REPEATS = 7
#: What the daemon cannot do without: its model's difference equations are precompiled.
LIBRARIES = "import numpy, pydantic, structlog, yaml, pymodbus.client"
DAEMON_S = 20


def verdict(passed: bool) -> str:
    return "PASS" if passed else "FAIL"


def environment() -> str:
    """What produced the figures; asked of a child, so this process stays small (see below)."""
    script = (
        "import platform, os, numpy, scipy; print(f'python {platform.python_version()}, "
        "numpy {numpy.__version__}, scipy {scipy.__version__}, {platform.machine()}, "
        "{os.cpu_count()} CPUs')"
    )
    return subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True
    ).stdout.strip()


def measured(argv: list[str], *, must_succeed: bool = False) -> tuple[float, float, float]:
    """Wall s, CPU s and peak RSS (MB) of one process.

    ``must_succeed``: a process that failed is an error, not a figure (a daemon that
    could not start would otherwise show as a small, passing footprint).
    """
    start = time.perf_counter()
    child = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    _, status, usage = os.wait4(child.pid, 0)
    wall = time.perf_counter() - start
    if must_succeed and status != 0:
        raise SystemExit(f"{' '.join(argv)} failed (wait status {status}): no figure")
    return wall, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024


def median_of(argv: list[str]) -> tuple[float, float, float]:
    runs = [measured(argv) for _ in range(REPEATS)]
    return tuple(statistics.median(r[i] for r in runs) for i in range(3))  # type: ignore[return-value]


def main() -> int:
    print(environment())
    compd = [sys.executable, "-m", "compd.cli"]
    with tempfile.TemporaryDirectory(dir="/tmp") as tmp:
        simulated, real = simulated_and_real(Path(tmp), ROOT)
        rows = [
            ("python -c pass (the floor)", [sys.executable, "-c", "pass"], None),
            (
                "every parser, eagerly (before)",
                [sys.executable, "-c", "from compd.cli import build_parser; build_parser()"],
                None,
            ),
            ("compd --help", [*compd, "--help"], 0.3),
            ("compd --version", [*compd, "--version"], 0.3),
            ("compd status (not running)", [*compd, "status", "--config", str(real)], 0.3),
            ("compd check-config (real machine)", [*compd, "check-config", str(real)], None),
        ]
        print(f"\n{'command':38} {'wall s':>8} {'CPU s':>8} {'RSS MB':>8}  target")
        passed = True
        for name, argv, target_s in rows:
            wall, cpu, rss = median_of(argv)
            ok = target_s is None or wall < target_s
            passed &= ok
            shown = f"< {target_s} s {verdict(ok)}" if target_s else ""
            print(f"{name:38} {wall:8.3f} {cpu:8.3f} {rss:8.1f}  {shown}")

        print(f"\ncompd run for {DAEMON_S} s: peak resident memory")
        machine = subprocess.Popen(
            [*compd, "simulate-machine", "--config", str(simulated)],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )  # fmt: skip
        try:
            time.sleep(3)
            run = ["run", "--duration-s", str(DAEMON_S), "--log-format", "json", "--config"]
            _, _, rss_numpy = measured([*compd, *run, str(real)], must_succeed=True)
        finally:
            machine.terminate()
            machine.wait()
        _, _, rss_sim = measured(
            [*compd, "run", "--config", str(simulated), "--duration-s", str(DAEMON_S),
             "--log-format", "json"], must_succeed=True,
        )  # fmt: skip
        _, _, rss_floor = measured([sys.executable, "-c", LIBRARIES])
        ok = rss_numpy < 60
        passed &= ok
        print(f"{'real machine, the bundled model':38} {rss_numpy:8.1f} MB  < 60 MB {verdict(ok)}")
        print(f"{'its libraries imported, nothing run':38} {rss_floor:8.1f} MB  (the floor)")
        print(f"{'simulated machine in the process':38} {rss_sim:8.1f} MB  (before: all in one)")
    return 0 if passed else 1


if __name__ == "__main__":
    sys.exit(main())
