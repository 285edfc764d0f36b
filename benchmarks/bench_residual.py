"""Per-tick cost of Swiss-lathe paper's residual forest, beside scikit-learn's ``predict`` on one sample.

The daemon evaluates the door residual model every tick: the door features
advance one step, then all trees are traversed at once
(:meth:`compd.model.residual.Forest.predict_one`). This fits a forest of
``--trees`` trees of depth <= ``--max-depth`` (default 100 and 12, the size
the target is stated for) on a synthetic door residue of two days at 10 s,
checks that compd's arrays predict what scikit-learn predicts (to 1e-9 um),
then times, per tick over ``--ticks`` ticks (median and p99, us):

- compd: ``ResidualModel.step`` (features and forest), ``Forest.predict_one``
  alone, and the increase of ``TickRunner.step`` on the benchmark model of
  :mod:`common` when ``disp_z_um`` gets the residual model;
- baseline: ``RandomForestRegressor.predict`` on one sample (``n_jobs=1``).

Per-tick figures are the best of 3 passes by p99 (one pass for the slow baseline).

And over a record: ``simulate``'s forest pass on a day at 1 Hz vs
``predict`` on the same features. Target: p99 of the step's CPU time per
tick < 2 ms (wall time is printed too; on a loaded machine its p99 is the
scheduler's, not compd's).
Run: ``PYTHONPATH=. python benchmarks/bench_residual.py [--trees N --max-depth D]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import gc
import time

import numpy as np
from common import BUSY_START, build_model, environment, verdict, week_signals
from sklearn.ensemble import RandomForestRegressor

from compd.model import TickRunner, compile_model
from compd.model.residual import DoorFeatures, ResidualModel
from compd.toolkit.residual import forest_from_sklearn

TARGET_P99_US = 2000.0


def door_signal(n: int, seed: int) -> np.ndarray:
    """Openings of 3-10 min every 10-40 min, at 10 s per sample."""
    rng = np.random.default_rng(seed)
    values: list[float] = []
    while len(values) < n:
        values += [0.0] * int(rng.integers(60, 240)) + [1.0] * int(rng.integers(18, 60))
    return np.asarray(values[:n])


def per_call_us(call, args_list, repeats: int = 3, clock=time.perf_counter_ns) -> np.ndarray:
    """Time of each call in us by ``clock``, GC off: of ``repeats`` passes, the one with the lowest p99.

    The best pass, as the other scripts report the best of several repeats: a
    busy machine preempts the process at random, which no code change fixes.
    With ``clock=time.thread_time_ns`` the figure is the CPU the call used,
    which preemption does not inflate.
    """
    passes = []
    for _ in range(repeats):
        times = np.empty(len(args_list))
        gc.disable()
        try:
            for i, args in enumerate(args_list):
                start = clock()
                call(*args)
                times[i] = (clock() - start) / 1000.0
        finally:
            gc.enable()
        passes.append(times)
    return min(passes, key=lambda t: float(np.percentile(t, 99)))


def row(label: str, times_us: np.ndarray) -> str:
    median, p99 = np.median(times_us), np.percentile(times_us, 99)
    return f"  {label:<46}{median:9.1f} {p99:9.1f}"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trees", type=int, default=100)
    parser.add_argument("--max-depth", type=int, default=12)
    parser.add_argument("--ticks", type=int, default=5000)
    args = parser.parse_args()

    features = DoorFeatures("door_open")
    door = door_signal(2 * 8640, seed=1)
    x, _ = features.record(door, 10.0, features.initial_state(door[0]))
    rng = np.random.default_rng(2)
    residue = -3.0 * np.tanh(x[:, 1] * 2) + 1.5 * x[:, 2] ** 2 + rng.normal(0, 0.3, door.size)
    regressor = RandomForestRegressor(
        n_estimators=args.trees, max_depth=args.max_depth, random_state=0, n_jobs=1
    )
    regressor.fit(x, residue)
    forest = forest_from_sklearn(regressor)
    residual = ResidualModel(features, forest)
    agree = float(np.max(np.abs(forest.predict(x) - regressor.predict(x))))

    ticks = min(args.ticks, x.shape[0])
    rows = [(x[i],) for i in range(ticks)]
    for i in range(200):  # warm-up
        forest.predict_one(x[i])
    forest_us = per_call_us(forest.predict_one, rows)
    # ~25 ms a call (joblib dispatch per predict): 300 calls give a stable median and p99.
    sklearn_us = per_call_us(regressor.predict, [(r[0][None],) for r in rows[:300]], repeats=1)
    state = features.initial_state(door[0])
    step_us = per_call_us(residual.step, [(state, v, 10.0) for v in door[:ticks]])
    step_cpu_us = per_call_us(
        residual.step, [(state, v, 10.0) for v in door[:ticks]], clock=time.thread_time_ns
    )

    # The benchmark model's tick, without and with the residual on disp_z_um.
    plain = build_model()
    outputs = tuple(
        dataclasses.replace(o, residual=residual) if o.name == "disp_z_um" else o
        for o in plain.outputs
    )
    stacked = dataclasses.replace(plain, outputs=outputs)
    tick_us = {}
    for label, model in (("plain", plain), ("stacked", stacked)):
        compiled = compile_model(model)
        names = compiled.signals
        base = tuple(n for n in names if n != "door_open")
        full = np.zeros((ticks, len(names)))
        full[:, [names.index(n) for n in base]] = week_signals(base, BUSY_START + ticks)[
            BUSY_START:
        ]
        if "door_open" in names:
            full[:, names.index("door_open")] = door[:ticks]
        runner = TickRunner(compiled, compiled.steady_state(full[0]))
        tick_us[label] = per_call_us(runner.step, [(r,) for r in full])

    day = np.repeat(x[:8640], 10, axis=0)  # a day at 1 Hz
    start = time.perf_counter()
    forest.predict(day)
    record_s = time.perf_counter() - start
    start = time.perf_counter()
    regressor.predict(day)
    sklearn_record_s = time.perf_counter() - start

    print(f"bench_residual: door residual forest per tick ({ticks} ticks)")
    print(f"  {environment()}")
    print(
        f"  forest: {forest.n_trees} trees, depth {forest.depth}, {forest.n_nodes} nodes; "
        f"max |compd - sklearn| = {agree:.1e} um"
    )
    print(f"  {'per tick (us)':<46}{'median':>9} {'p99':>9}")
    print(row("compd ResidualModel.step (features + forest)", step_us))
    print(row("  the same, CPU time of the thread", step_cpu_us))
    print(row("compd Forest.predict_one", forest_us))
    print(row("baseline sklearn predict, one sample (300 calls)", sklearn_us))
    print(row("TickRunner.step, benchmark model", tick_us["plain"]))
    print(row("TickRunner.step, same + residual on disp_z_um", tick_us["stacked"]))
    print(
        f"  over a day at 1 Hz (86,400 samples): compd {record_s:.2f} s, "
        f"sklearn predict {sklearn_record_s:.2f} s"
    )
    fast = float(np.percentile(step_cpu_us, 99)) < TARGET_P99_US
    same = agree <= 1e-9
    print(f"  {f'target: residual step CPU p99 < {TARGET_P99_US:.0f} us':<46}{verdict(fast)}")
    print(f"  {'check: compd predicts as sklearn to 1e-9 um':<46}{verdict(same)}")
    return 0 if fast and same else 1


if __name__ == "__main__":
    raise SystemExit(main())
