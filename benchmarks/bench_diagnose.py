"""Cost of the residue correlation test and of ``diagnose`` beside direct baselines, one BLAS thread.

``compd diagnose`` and the report run the residue test on whole data files:
the residue's autocorrelation and its cross-correlation with every candidate
input, with Bartlett bounds (which need every input's autocorrelation too).

1. ``correlate`` of a residue with 6 inputs over 288,000 samples (80 h at
   1 Hz), lags 0..7,200 (2 h). Baselines: ``scipy.signal.correlate`` with
   ``method="fft"``, one call per correlation the test needs (residue
   auto, 6 cross, 6 input autos), timed in full; and ``np.correlate`` (the
   direct sum), timed over a 20,000-sample slice and **extrapolated** by
   ``N^2`` (it computes all ``2N - 1`` lags at ``O(N)`` each).
   Target: < 50 ms.
2. ``diagnose_residue`` over 24 h at 1 Hz with 12 candidates. Baseline: the
   same one-lag cross-validation written the obvious way, a least-squares
   fit (``np.linalg.lstsq``) on the training rows per candidate, time
   constant and fold, timed for one candidate and **extrapolated** x12. The
   baseline does less than compd: no refinement of the time constant, no
   two-lag models, no chance level. Target: < 10 s.

Both are first checked to agree with their baselines.
Run: ``PYTHONPATH=. python benchmarks/bench_diagnose.py`` from the repository root.
"""

from __future__ import annotations

import os

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_name] = "1"  # one BLAS thread, set before numpy is imported

import itertools  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402

import numpy as np  # noqa: E402
import scipy.signal  # noqa: E402
from common import BUSY_START, environment, verdict, week_signals  # noqa: E402
from numpy.testing import assert_allclose  # noqa: E402

from compd.model.correlation import correlate  # noqa: E402
from compd.model.diagnose import diagnose_residue  # noqa: E402
from compd.model.lagscore import fit_candidate, lag_bank, time_constant_bank  # noqa: E402

CORR_SAMPLES = 288_000
MAX_LAG = 7_200
SLICE = 20_000
DAY = 86_400
MAX_CORRELATE_S = 0.05
MAX_DIAGNOSE_S = 10.0
ORDER = (
    "T_spindle_degC",
    "T_bed_degC",
    "T_column_degC",
    "T_ambient_degC",
    "T_coolant_degC",
    "spindle_speed_rpm",
    "spindle_power_kw",
)


def best_s(run: Callable[[], object], repeats: int = 5) -> float:
    """Best wall time of ``repeats`` calls of ``run()``, in seconds."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter_ns()
        run()
        times.append((time.perf_counter_ns() - start) / 1e9)
    return min(times)


def residue_and_inputs(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A residue driven by spindle power (2 um/kW, 30-min lag), the 6 other signals, and the power."""
    signals = week_signals(ORDER, n_samples=n, seed=1)
    power = signals[:, ORDER.index("spindle_power_kw")]
    pole = np.exp(-1.0 / 1800.0)
    residue = 2.0 * scipy.signal.lfilter([0.0, 1.0 - pole], [1.0, -pole], power - power[0])
    residue += np.random.default_rng(2).normal(0.0, 0.2, n)
    return residue, signals[:, :6].T.copy(), power


def scipy_fft_correlations(residue: np.ndarray, inputs: np.ndarray) -> list[np.ndarray]:
    """The 13 correlations the test needs, one ``scipy.signal.correlate(method='fft')`` each."""
    e = residue - residue.mean()
    u = inputs - inputs.mean(axis=1, keepdims=True)
    pairs = [(e, e)] + [(e, x) for x in u] + [(x, x) for x in u]
    return [scipy.signal.correlate(a, b, mode="full", method="fft") for a, b in pairs]


def direct_cross(residue: np.ndarray, inputs: np.ndarray, max_lag: int) -> np.ndarray:
    """Normalised cross-correlations at lags 0..max_lag by ``np.correlate`` (direct sums)."""
    e = residue - residue.mean()
    rows = []
    for x in inputs:
        u = x - x.mean()
        full = np.correlate(e, u, mode="full")
        rows.append(full[len(e) - 1 : len(e) + max_lag] / np.sqrt((e @ e) * (u @ u)))
    return np.array(rows)


def lstsq_cv_explained(
    residue: np.ndarray, u: np.ndarray, taus: np.ndarray, folds: int = 5
) -> float:
    """Best one-lag blocked-CV explained share, by a least-squares fit per time constant and fold."""
    n = len(residue)
    edges = np.linspace(0, n, folds + 1).astype(int)
    spread = np.sum((residue - residue.mean()) ** 2)
    best = -np.inf
    for x in lag_bank(u, taus, 1.0):
        design = np.column_stack([np.ones(n), x])
        sse = 0.0
        for a, b in itertools.pairwise(edges):
            train = np.r_[0:a, b:n]
            beta, *_ = np.linalg.lstsq(design[train], residue[train], rcond=None)
            sse += float(np.sum((residue[a:b] - design[a:b] @ beta) ** 2))
        best = max(best, 100.0 * (1.0 - np.sqrt(sse / spread)))
    return float(best)


def bench_correlate() -> bool:
    residue, inputs, _ = residue_and_inputs(CORR_SAMPLES)
    busy = slice(BUSY_START, BUSY_START + SLICE)  # the spindle runs: no constant input
    part_e, part_u = residue[busy], inputs[:, busy]
    assert_allclose(
        correlate(part_e, part_u, 400).cross, direct_cross(part_e, part_u, 400), atol=1e-10
    )
    correlate(residue, inputs, MAX_LAG)  # warm-up
    compd_s = best_s(lambda: correlate(residue, inputs, MAX_LAG), repeats=10)
    scipy_s = best_s(lambda: scipy_fft_correlations(residue, inputs), repeats=3)
    direct_slice_s = best_s(lambda: direct_cross(part_e, part_u[:1], 1), repeats=3)
    scale = (CORR_SAMPLES / SLICE) ** 2
    direct_s = direct_slice_s * 13 * scale
    print(
        f"bench_diagnose: residue auto- and cross-correlation with 6 inputs, "
        f"{CORR_SAMPLES:,} samples, lags 0..{MAX_LAG:,}, with Bartlett bounds"
    )
    print(f"  {environment()}, 1 BLAS thread")
    print(f"  {'compd correlate (best of 10)':<48}{compd_s * 1e3:9.1f} ms")
    print(f"  {'baseline: 13 x scipy correlate fft (best of 3)':<48}{scipy_s * 1e3:9.1f} ms")
    print(
        f"  {'baseline: 13 x np.correlate direct':<48}{direct_s:9.0f} s   EXTRAPOLATED: "
        f"{direct_slice_s * 1e3:.0f} ms for one on {SLICE:,} samples x 13 x {scale:.0f}"
    )
    fast = compd_s < MAX_CORRELATE_S
    print(f"  {f'target: correlate < {MAX_CORRELATE_S * 1e3:.0f} ms':<48}{verdict(fast)}")
    return fast


def bench_diagnose() -> bool:
    residue, inputs, power = residue_and_inputs(DAY)
    rng = np.random.default_rng(3)
    extra = {
        "spindle_power_kw": power,
        "door_open": (rng.random(DAY) < 0.002).astype(float),
        "feed_x_mm_per_min": np.abs(rng.normal(0.0, 1000.0, DAY)),
        "walk_a": np.cumsum(rng.normal(size=DAY)),
        "walk_b": np.cumsum(rng.normal(size=DAY)),
        "T_motor_degC": inputs[0] + rng.normal(0.0, 0.05, DAY),
    }
    candidates = {name: inputs[i] for i, name in enumerate(ORDER[:6])} | extra
    assert len(candidates) == 12
    taus = time_constant_bank(1.0, DAY)
    u = (power - power[0]) / np.std(power - power[0])
    grid = fit_candidate(residue, u, taus, 1.0, pair_margin_percent=np.inf, refine=False)
    baseline_percent = lstsq_cv_explained(residue, u, taus)
    assert_allclose(grid.explained_percent, baseline_percent, rtol=0.0, atol=1e-6)

    compd_s = best_s(lambda: diagnose_residue(residue, candidates, 1.0), repeats=3)
    baseline_one_s = best_s(lambda: lstsq_cv_explained(residue, u, taus), repeats=1)
    best = diagnose_residue(residue, candidates, 1.0).candidates[0]
    print(f"bench_diagnose: diagnose 24 h at 1 Hz ({DAY:,} samples), 12 candidates")
    print(f"  {'compd diagnose_residue (best of 3)':<48}{compd_s:9.2f} s")
    print(
        f"  {'baseline: lstsq per candidate, tau and fold':<48}{baseline_one_s * 12:9.2f} s   "
        f"EXTRAPOLATED: {baseline_one_s:.2f} s for one candidate x 12 (one-lag only)"
    )
    print(
        f"  ranked first: {best.signal}, {best.explained_percent:.1f} % explained on held-out "
        f"data (chance {best.chance_percent:.1f} %), tau {best.time_constant_s:.0f} s (true 1800), "
        f"gain {best.gain_um_per_unit:.3f} um/kW (true 2.0)"
    )
    print(
        f"  on the tau grid alone: compd {grid.explained_percent:.6f} %, "
        f"lstsq baseline {baseline_percent:.6f} %"
    )
    fast = compd_s < MAX_DIAGNOSE_S
    print(f"  {f'target: diagnose < {MAX_DIAGNOSE_S:.0f} s':<48}{verdict(fast)}")
    return fast


def main() -> int:
    fast_correlate = bench_correlate()
    print()
    fast_diagnose = bench_diagnose()
    return 0 if fast_correlate and fast_diagnose else 1


if __name__ == "__main__":
    sys.exit(main())
