"""Per-tick cost of ``TickRunner.step`` beside one ``scipy.signal.lfilter`` call per sub-model per tick.

The daemon calls ``step`` once a second per model, so its cost bounds how many
models (and how much else) one core can serve. The baseline is the obvious
way to run the same filters tick by tick: the same input gathering as
``step``, then ``lfilter(b, a, [u], zi=z)`` per sub-model, carrying ``zi``
forward. Both run the benchmark model of :mod:`common` over the same 20,000
samples; their outputs are checked equal (to ``common.AGREE_UM``, the
rounding this model allows) before anything is timed, so the comparison is
of the same work.

Targets: ``step`` under 50 us per tick, and at least 5x faster than the baseline.
Run: ``PYTHONPATH=. python benchmarks/bench_step.py`` from the repository root.
"""

from __future__ import annotations

import gc
import statistics
import sys
import time
from collections.abc import Callable, Sequence

import numpy as np
import scipy.signal
from common import AGREE_UM, BUSY_START, build_compiled, environment, verdict, week_signals
from numpy.testing import assert_allclose

from compd.errors import ModelError
from compd.model import CompiledModel, ModelState, TickRunner

TICKS = 20_000
REPEATS = 5
MAX_US_PER_TICK = 50.0
MIN_SPEEDUP = 5.0


class LfilterTicker:
    """The baseline: ``TickRunner.step``'s input gathering, then one ``lfilter`` per sub-model."""

    def __init__(self, compiled: CompiledModel, state: ModelState) -> None:
        self.compiled = compiled
        self._z = [row.copy() for row in state.z]
        self._reference = state.reference.copy()
        self._n_signals = len(compiled.signals)
        self._extended = compiled.extended(np.zeros(self._n_signals))
        self._output_gated = ~compiled.gate_on_input

    def step(self, signals: np.ndarray) -> np.ndarray:
        compiled = self.compiled
        extended = self._extended
        extended[: self._n_signals] = signals
        if not np.isfinite(extended).all():
            raise ModelError("non-finite signal value")
        u = extended[compiled.plus_index] - extended[compiled.minus_index] - self._reference
        gate = compiled.gates_open(extended)
        u *= np.where(compiled.gate_on_input, gate, 1.0)
        y = np.empty(compiled.n_submodels)
        for row in range(compiled.n_submodels):
            out, self._z[row] = scipy.signal.lfilter(
                compiled.b[row], compiled.a[row], [u[row]], zi=self._z[row]
            )
            y[row] = out[0]
        contributions = y * compiled.gain * np.where(self._output_gated, gate, 1.0)
        return compiled.output_matrix @ contributions


def outputs_of(runner: TickRunner | LfilterTicker, rows: Sequence[np.ndarray]) -> np.ndarray:
    """Every tick's outputs; also the warm-up before timing."""
    return np.array([runner.step(row) for row in rows])


def us_per_tick(
    make: Callable[[], TickRunner | LfilterTicker], rows: Sequence[np.ndarray]
) -> list[float]:
    """Microseconds per tick of each repeat, a fresh runner each time, GC off as in ``timeit``."""
    figures = []
    for _ in range(REPEATS):
        step = make().step
        gc.disable()
        try:
            start = time.perf_counter_ns()
            for row in rows:
                step(row)
            elapsed_ns = time.perf_counter_ns() - start
        finally:
            gc.enable()
        figures.append(elapsed_ns / len(rows) / 1e3)
    return figures


def main() -> int:
    compiled = build_compiled()
    signals = week_signals(compiled.signals, n_samples=BUSY_START + TICKS)[BUSY_START:]
    rows = list(signals)
    state = compiled.rest_state(signals[0])

    def make_compd() -> TickRunner:
        return TickRunner(compiled, state)

    def make_baseline() -> LfilterTicker:
        return LfilterTicker(compiled, state)

    compd_out, baseline_out = outputs_of(make_compd(), rows), outputs_of(make_baseline(), rows)
    assert_allclose(compd_out, baseline_out, rtol=0.0, atol=AGREE_UM)
    compd_us, baseline_us = us_per_tick(make_compd, rows), us_per_tick(make_baseline, rows)
    compd_median, baseline_median = statistics.median(compd_us), statistics.median(baseline_us)
    speedup = baseline_median / compd_median

    print(
        f"bench_step: one tick of {compiled.n_submodels} sub-models x order {compiled.n_states}, "
        f"{len(compiled.output_names)} outputs, {len(compiled.signals)} signals"
    )
    print(f"  {environment()}")
    print(
        f"  {TICKS:,} ticks x {REPEATS} repeats after a warm-up pass; median (min-max) us per tick"
    )
    for label, figures in (
        ("compd TickRunner.step", compd_us),
        ("baseline: lfilter per sub-model", baseline_us),
    ):
        print(
            f"  {label:<42}{statistics.median(figures):8.1f} us  "
            f"({min(figures):.1f}-{max(figures):.1f})"
        )
    print(f"  {'speed-up':<42}{speedup:8.1f} x")
    max_diff = float(np.max(np.abs(compd_out - baseline_out)))
    print(
        f"  outputs agree within {AGREE_UM} um (see common.AGREE_UM): max |difference| "
        f"{max_diff:.1e} um on outputs up to {np.max(np.abs(compd_out)):.0f} um"
    )
    fast = compd_median < MAX_US_PER_TICK
    ahead = speedup >= MIN_SPEEDUP
    print(f"  {f'target: step < {MAX_US_PER_TICK:.0f} us per tick':<42}{verdict(fast)}")
    print(f"  {f'target: >= {MIN_SPEEDUP:.0f}x faster than the baseline':<42}{verdict(ahead)}")
    return 0 if fast and ahead else 1


if __name__ == "__main__":
    sys.exit(main())
