"""Cost of ``simulate`` over one week at 1 Hz beside a pure-Python sample-by-sample loop.

``compd evaluate`` and model identification run ``simulate`` over whole data
files, often many times over (one run per candidate model), so a week of
1 Hz data must take well under a second. The baseline is the difference
equation written out with Python floats, one sample and one sub-model at a
time, as a script without numpy would do it. It is too slow to run over the
whole week inside the time budget, so it is timed over a 20,000-sample slice
and extrapolated linearly (the loop's cost per sample does not depend on the
data); the output says so. On that slice both are checked to give the same
outputs (to ``common.AGREE_UM``) before anything is timed.

Also printed: simulate's peak extra memory (tracemalloc), since a month of
data at 1 Hz has to fit in a small industrial PC too.

Beside it, the simulated machine's thermal twin (:func:`compd.sim.thermal.simulate_record`)
over 24 h at 1 s with a spindle speed change every 5 min, best of 3: it
runs for every simulated shift and every demo, so it has its own budget.

Targets: simulate of one week under 0.5 s; the twin's day under 2 s.
Run: ``PYTHONPATH=. python benchmarks/bench_simulate.py`` from the repository root.
"""

from __future__ import annotations

import sys
import time
import tracemalloc
from collections.abc import Callable

import numpy as np
from common import (
    AGREE_UM,
    BUSY_START,
    WEEK_SAMPLES,
    build_compiled,
    environment,
    verdict,
    week_signals,
)
from numpy.testing import assert_allclose

from compd.model import CompiledModel, ModelState, simulate
from compd.sim.machine import MachineParameters
from compd.sim.thermal import InputRecord, simulate_record

SLICE = 20_000
REPEATS = 3
MAX_SIMULATE_S = 0.5


def python_loop(compiled: CompiledModel, signals: np.ndarray, state: ModelState) -> np.ndarray:
    """Outputs ``(N, n_outputs)`` from the difference equation in Python floats, from rest.

    ``y(k) = sum_i b_i u(k-i) - sum_{i>=1} a_i y(k-i)`` (``a0 == 1``, delay
    folded into ``b``), with zero histories: the same start as a state with
    ``z == 0``.
    """
    assert not state.z.any(), "the loop starts from rest: pass compiled.rest_state(...)"
    owners = compiled.output_matrix.argmax(axis=0).tolist()
    subs = [
        (
            compiled.b[s].tolist(),
            compiled.a[s, 1:].tolist(),
            int(compiled.plus_index[s]),
            int(compiled.minus_index[s]),
            float(state.reference[s]),
            int(compiled.gate_index[s]),
            float(compiled.gate_threshold[s]),
            float(compiled.gate_sign[s]),
            bool(compiled.gate_on_input[s]),
            float(compiled.gain[s]),
            owners[s],
            [0.0] * compiled.b.shape[1],
            [0.0] * compiled.n_states,
        )
        for s in range(compiled.n_submodels)
    ]
    n_outputs = len(compiled.output_names)
    result = []
    for sample in signals.tolist():
        extended = [*sample, 0.0, 1.0]
        outputs = [0.0] * n_outputs
        for (
            b,
            a,
            plus,
            minus,
            ref,
            gate,
            threshold,
            sign,
            on_input,
            gain,
            owner,
            u_past,
            y_past,
        ) in subs:
            opened = (extended[gate] - threshold) * sign > 0.0
            u = extended[plus] - extended[minus] - ref if opened or not on_input else 0.0
            u_past.pop()
            u_past.insert(0, u)
            y = sum(bi * ui for bi, ui in zip(b, u_past, strict=True))
            y -= sum(ai * yi for ai, yi in zip(a, y_past, strict=True))
            if y_past:
                y_past.pop()
                y_past.insert(0, y)
            if opened or on_input:
                outputs[owner] += gain * y
        result.append(outputs)
    return np.array(result)


def best_s(run: Callable[[], object], repeats: int = REPEATS) -> float:
    """Best wall time of ``repeats`` calls of ``run()``, in seconds."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter_ns()
        run()
        times.append((time.perf_counter_ns() - start) / 1e9)
    return min(times)


def peak_extra_mb(compiled: CompiledModel, signals: np.ndarray, state: ModelState) -> float:
    """Peak memory allocated during one simulate call above what was held before it, in MB."""
    tracemalloc.start()
    try:
        before, _ = tracemalloc.get_traced_memory()
        tracemalloc.reset_peak()
        simulate(compiled, signals, state)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return (peak - before) / 1e6


MAX_TWIN_DAY_S = 2.0


def twin_day_s() -> float:
    """Best of 3 of the thermal twin over 24 h at 1 s, spindle speed changing every 5 min."""
    n = 86_400
    speed = np.repeat(np.resize([0.0, 4000.0, 8000.0, 12000.0], n // 300), 300)
    zeros = np.zeros(n)
    ambient = np.full(n, 20.0)
    record = InputRecord(ambient, ambient.copy(), speed, zeros, zeros, zeros, zeros)
    return best_s(lambda: simulate_record(record, 1.0, params=MachineParameters()))


def main() -> int:
    compiled = build_compiled()
    week = week_signals(compiled.signals)
    state = compiled.rest_state(week[0])
    part = week[BUSY_START : BUSY_START + SLICE]
    part_state = compiled.rest_state(part[0])

    loop_out = python_loop(compiled, part, part_state)
    simulate_out = simulate(compiled, part, part_state).outputs
    assert_allclose(simulate_out, loop_out, rtol=0.0, atol=AGREE_UM)

    simulate(compiled, week, state)  # warm-up
    simulate_s = best_s(lambda: simulate(compiled, week, state))
    loop_slice_s = best_s(lambda: python_loop(compiled, part, part_state))
    loop_week_s = loop_slice_s * WEEK_SAMPLES / SLICE
    memory_mb = peak_extra_mb(compiled, week, state)

    print(
        f"bench_simulate: simulate over one week at 1 Hz ({WEEK_SAMPLES:,} samples), "
        f"{compiled.n_submodels} sub-models x order {compiled.n_states}"
    )
    print(f"  {environment()}")
    print(f"  {'compd simulate (best of 3)':<42}{simulate_s:8.3f} s")
    print(
        f"  {'baseline: pure-Python loop (best of 3)':<42}{loop_week_s:8.1f} s  "
        f"EXTRAPOLATED: {loop_slice_s:.3f} s for {SLICE:,} samples x {WEEK_SAMPLES / SLICE:.2f}"
    )
    print(f"  {'speed-up':<42}{loop_week_s / simulate_s:8.0f} x")
    print(
        f"  {'peak extra memory of simulate':<42}{memory_mb:8.0f} MB  "
        f"(tracemalloc; the signals passed in are {week.nbytes / 1e6:.0f} MB)"
    )
    max_diff = float(np.max(np.abs(simulate_out - loop_out)))
    print(
        f"  outputs agree within {AGREE_UM} um on the slice (see common.AGREE_UM): "
        f"max |difference| {max_diff:.1e} um"
    )
    fast = simulate_s < MAX_SIMULATE_S
    print(f"  {f'target: simulate < {MAX_SIMULATE_S} s':<42}{verdict(fast)}")
    twin_s = twin_day_s()
    print(f"  {'thermal twin, 24 h at 1 s (best of 3)':<42}{twin_s:8.3f} s")
    twin_fast = twin_s < MAX_TWIN_DAY_S
    print(f"  {f'target: twin day < {MAX_TWIN_DAY_S} s':<42}{verdict(twin_fast)}")
    return 0 if fast and twin_fast else 1


if __name__ == "__main__":
    sys.exit(main())
