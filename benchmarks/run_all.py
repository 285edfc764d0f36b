"""Run every benchmark, each in its own interpreter, and exit non-zero if any target fails.

A fresh process per script keeps one benchmark's allocations and warm caches
out of the next one's figures (tracemalloc peaks in particular). The
checkout's own ``compd`` is put first on ``PYTHONPATH`` so the figures are
those of the working tree, not of an installed copy. For humans, not CI:
timings on shared runners are too noisy to gate a merge on.

Run: ``python benchmarks/run_all.py`` from anywhere.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
SCRIPTS = (
    "bench_step.py",
    "bench_simulate.py",
    "bench_identify.py",
    "bench_real_identify.py",
    "bench_machines.py",
    "bench_tick.py",
    "bench_recorder_parquet.py",
    "bench_metrics.py",
    "bench_http_flood.py",
    "bench_diagnose.py",
    "bench_residual.py",
    "bench_report.py",
    "bench_modbus.py",
    "bench_gateway.py",
    "bench_opcua.py",
    "bench_serial.py",
    "bench_all_drivers.py",
    "bench_startup.py",
    "bench_telemetry.py",
    "soak_faults.py",
)
#: Arguments per script: the tick benchmark's quick run (600 ticks at 0.1 s, 1 minute);
#: its full run (600 real 1 Hz ticks, 10 minutes) is ``python benchmarks/bench_tick.py``.
ARGS = {
    "bench_tick.py": ["--ticks", "600", "--period-s", "0.1"],
    # Quick as well (2 x 30 s + 20 s); the full run is 2 x 600 real 1 Hz ticks and 60 s of fleet.
    "bench_telemetry.py": ["--ticks", "300", "--period-s", "0.1", "--fleet-s", "20"],
    "bench_metrics.py": ["--ticks", "60"],  # 2 minutes; the full run is 2 x 600 ticks at 1 Hz
}


def main() -> int:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(HERE.parent), env.get("PYTHONPATH")]))
    results = {}
    for script in SCRIPTS:
        results[script] = subprocess.run(
            [sys.executable, str(HERE / script), *ARGS.get(script, [])], env=env
        ).returncode
        print()
    for script, code in results.items():
        status = {0: "all targets PASS", 1: "a target FAILED"}.get(code, f"crashed (exit {code})")
        print(f"{script:<20}{status}")
    return 0 if all(code == 0 for code in results.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
