"""Time to build the HTML report of a day-long record at 1 Hz, diagnosis included.

``compd report`` on a day of 1 Hz logging (86,400 samples, 4 signals, one
axis, the bundled gated ARX model) evaluates the model, runs the residue
diagnosis, decimates the lines and writes one self-contained page. It used
to be a timed assertion in ``tests/report/test_page.py``; the size check
stays there, the time is measured here (best of 3).

Target: < 20 s on 2 cores.
Run: ``PYTHONPATH=. python benchmarks/bench_report.py`` from the repository root.
"""

from __future__ import annotations

import sys
import time

from common import environment, verdict

from compd.files.modelfile import load_model
from compd.report.gather import gather
from compd.report.page import build_html
from compd.toolkit.evaluate import evaluate
from tests.report.conftest import GATED, day_record

MAX_REPORT_S = 20.0


def main() -> int:
    data = day_record()
    model = load_model(GATED)
    times, size_mb = [], 0.0
    for _ in range(3):
        start = time.perf_counter()
        html = build_html(gather(evaluate(model, data)))
        times.append(time.perf_counter() - start)
        size_mb = len(html.encode()) / 1e6
    best = min(times)
    ok = best < MAX_REPORT_S
    print(f"bench_report: report of 24 h at 1 Hz ({len(data.time_s):,} samples); {environment()}")
    print(f"  {'compd report (best of 3)':<42}{best:8.2f} s   ({size_mb:.1f} MB of HTML)")
    print(f"  {f'target: report < {MAX_REPORT_S:.0f} s':<42}{verdict(ok)}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
