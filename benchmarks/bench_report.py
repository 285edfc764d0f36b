"""Time and size of the HTML report: a day at 1 Hz (time), a 16 h twin shift at 1 Hz (size).

``compd report`` on a day of 1 Hz logging (86,400 samples, 4 signals, one
axis, the bundled gated ARX model) evaluates the model, runs the residue
diagnosis, decimates the lines and writes one self-contained page. It used
to be a timed assertion in ``tests/report/test_page.py``; the size check
stays there, the time is measured here (best of 3).

The size is measured on the report a user writes of a 16 h shift of the
thermal twin at 1 Hz (``compd twin --scenario shift --hours 16``, 57,601
samples, 16 signals) with the twin's bundled model
(``config/simulated_model.yaml``): 9.0 MB before the report inlined
plotly.js's basic bundle (1.2 MB instead of 4.8 MB) and drew each line from
at most 1,600 points.

Targets: report < 20 s on 2 cores; 16 h report < 2 MB.
Run: ``PYTHONPATH=. python benchmarks/bench_report.py`` from the repository root.
"""

from __future__ import annotations

import contextlib
import io
import sys
import tempfile
import time
from pathlib import Path

from common import environment, verdict

from compd.cli import main as compd
from compd.files.data import load_data
from compd.files.modelfile import load_model
from compd.report.gather import gather
from compd.report.page import build_html
from compd.toolkit.evaluate import evaluate
from tests.report.conftest import CONFIG, GATED, day_record

MAX_REPORT_S = 20.0
MAX_SHIFT_MB = 2.0
#: The 16 h twin shift's report before the partial plotly.js bundle and lighter lines.
BEFORE_SHIFT_MB = 9.0


def shift_report_mb() -> float:
    """Size of the report of a 16 h twin shift at 1 Hz with the twin's bundled model, MB."""
    with tempfile.TemporaryDirectory() as tmp:
        csv = Path(tmp) / "shift16.csv"
        with contextlib.redirect_stdout(io.StringIO()):
            compd(["twin", "--scenario", "shift", "--hours", "16", "--out", str(csv)])
        model = load_model(CONFIG / "simulated_model.yaml")
        html = build_html(gather(evaluate(model, load_data(csv))))
    return len(html.encode()) / 1e6


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
    shift_mb = shift_report_mb()
    fast, small = best < MAX_REPORT_S, shift_mb < MAX_SHIFT_MB
    print(f"bench_report: report of 24 h at 1 Hz ({len(data.time_s):,} samples); {environment()}")
    print(f"  {'compd report (best of 3)':<42}{best:8.2f} s   ({size_mb:.1f} MB of HTML)")
    print(f"  {f'target: report < {MAX_REPORT_S:.0f} s':<42}{verdict(fast)}")
    print(
        f"  {'report of a 16 h twin shift at 1 Hz':<42}{shift_mb:8.2f} MB  "
        f"(before: {BEFORE_SHIFT_MB:.1f} MB, 4.8 MB of it plotly.js)"
    )
    print(f"  {f'target: 16 h report < {MAX_SHIFT_MB:.0f} MB':<42}{verdict(small)}")
    return 0 if fast and small else 1


if __name__ == "__main__":
    sys.exit(main())
