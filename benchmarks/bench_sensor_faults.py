"""Failing sensors on the bundled simulated machine: is compd ever silently wrong? (issues 33 and 41).

Each run: the bundled config and model (``bundled:simulated.yaml``), a
production shift (6 h, seed 1, compd on virtual time in this process) and one
case of faults (``simulation.faults``). The cases are data, in two tables:

- issue 33's, each kind on each model input at ``--at-s`` (2 h): a plausible
  wrong value (+15 and -25 degC off the truth, 1 h), a 40 s glitch to 60 degC,
  a 4 h freeze, a wire break reading high (327.67), low (-200) or NaN (1 h);
- issue 41's: slow drifts (the spindle +2 degC/h, the column front +0.5 degC/h,
  the air +1 degC/h, 4 h from 1 h), offsets inside the plausibility tolerance
  (spindle +8 degC, column front +2.5 degC, 1 h), two sensors at once
  (spindle +15 and headstock -25 degC; the column frozen and the air +10 degC).

Printed per case: the compensated max |error| on Z (um), the issue's bound (3x
the fault-free run's max, same seed and length), the **silent time** (the
seconds the axis was off by more than the bound while the status word said OK,
``status & 0b11 == 0``: the error nobody was told of), when the status first
showed degraded after the fault, how long a stand-in was used, and the verdict
of issue 41's "Done when": PASS if the max is within the bound, or the silent
time is at most 600 s. ``--baseline`` adds the max without the plausibility
check (``plausibility.enabled: false``, no stuck detection: compd before issue 33).

Run: ``python benchmarks/bench_sensor_faults.py [--cases issue41|issue33|all|NAME,..]
[--inputs A,B] [--kinds K,..] [--seed N] [--at-s S] [--hours H]`` (about 30 s a run).
"""

from __future__ import annotations

import argparse
import asyncio
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from simconfig import bundled_doc  # noqa: E402

from compd.cli.serving import configure_logging  # noqa: E402
from compd.service.config.loading import load_config  # noqa: E402
from compd.service.loop.signals import Health  # noqa: E402
from compd.sim.plc.run import run_simulation  # noqa: E402

AXIS = "Z"
#: The issue's "Done when": the status may be OK for at most this long while the error is beyond the bound.
SILENT_LIMIT_S = 600.0
#: ... the bound being this many times the fault-free run's max |error|.
BOUND_FACTOR = 3.0
#: A status word with either level bit set is not OK (degraded or faulted).
LEVEL_BITS = 0b11

AT_S = 7200.0
INPUTS = ("T_spindle_degC", "T_headstock_degC", "T_column_front_degC", "T_ambient_degC")
#: Issue 33's kinds, each struck on each input of ``--inputs`` at ``--at-s``.
KINDS: dict[str, dict[str, Any]] = {
    "+15 degC": {"kind": "offset", "value": 15, "duration_s": 3600},
    "-25 degC": {"kind": "offset", "value": -25, "duration_s": 3600},
    "glitch 40 s": {"kind": "value", "value": 60, "duration_s": 40},
    "freeze 4 h": {"kind": "stuck", "duration_s": 4 * 3600 - 1},
    "break high": {"kind": "value", "value": 327.67, "duration_s": 3600},
    "break low": {"kind": "value", "value": -200, "duration_s": 3600},
    "break NaN": {"kind": "nan", "duration_s": 3600},
}
#: Issue 41's cases: each a list of faults, ``at_s`` as the issue gives it (``--at-s`` moves them all).
ISSUE41: dict[str, list[dict[str, Any]]] = {
    "spindle drift +2 degC/h": [
        {"signal": "T_spindle_degC", "kind": "drift", "rate_per_h": 2.0, "at_s": 3600, "duration_s": 4 * 3600},
    ],
    "column front drift +0.5 degC/h": [
        {"signal": "T_column_front_degC", "kind": "drift", "rate_per_h": 0.5, "at_s": 3600, "duration_s": 4 * 3600},
    ],
    "air drift +1 degC/h": [
        {"signal": "T_ambient_degC", "kind": "drift", "rate_per_h": 1.0, "at_s": 3600, "duration_s": 4 * 3600},
    ],
    "spindle +8 degC": [
        {"signal": "T_spindle_degC", "kind": "offset", "value": 8.0, "at_s": AT_S, "duration_s": 3600},
    ],
    "column front +2.5 degC": [
        {"signal": "T_column_front_degC", "kind": "offset", "value": 2.5, "at_s": AT_S, "duration_s": 3600},
    ],
    "spindle +15, headstock -25": [
        {"signal": "T_spindle_degC", "kind": "offset", "value": 15.0, "at_s": AT_S, "duration_s": 3600},
        {"signal": "T_headstock_degC", "kind": "offset", "value": -25.0, "at_s": AT_S, "duration_s": 3600},
    ],
    "column stuck, air +10": [
        {"signal": "T_column_front_degC", "kind": "stuck", "at_s": AT_S, "duration_s": 3600},
        {"signal": "T_ambient_degC", "kind": "offset", "value": 10.0, "at_s": AT_S, "duration_s": 3600},
    ],
}  # fmt: skip


@dataclass(frozen=True)
class Run:
    """One run's figures on the axis."""

    max_um: float
    #: Per tick: |compensated error| (um) and whether the status word said OK.
    errors_um: tuple[float, ...]
    ok: tuple[bool, ...]
    period_s: float
    #: Seconds from the first fault to the status first not OK (None: never).
    degraded_after_s: float | None
    #: Ticks an input was estimated from the others (a stand-in), summed over inputs.
    estimated: int

    def silent_s(self, bound_um: float) -> float:
        """Seconds the axis was off by more than ``bound_um`` while the status word said OK."""
        silent = sum(
            1 for e, ok in zip(self.errors_um, self.ok, strict=True) if ok and e > bound_um
        )
        return silent * self.period_s


def run(
    faults: Sequence[dict[str, Any]], *, seed: int, hours: float, baseline: bool = False
) -> Run:
    """The bundled machine under ``faults``; the truth and the status at every tick."""
    directory, doc = bundled_doc("bench-sf-")
    doc["simulation"] = {
        "scenario": "production",
        "hours": hours,
        "seed": seed,
        "faults": list(faults),
    }
    if baseline:
        doc["plausibility"] = {"enabled": False}
        for name in INPUTS:
            doc["signals"][name]["checks"]["stuck_s"] = None
    (directory / "c.yaml").write_text(yaml.safe_dump(doc))
    config = load_config(directory / "c.yaml")
    errors: list[float] = []
    ok: list[bool] = []
    times: list[float] = []
    estimated = 0

    def tick(_service: Any, machine: Any, record: Any) -> None:
        nonlocal estimated
        errors.append(abs(machine.truth_now()[AXIS][2]))
        ok.append(record.status & LEVEL_BITS == 0)
        times.append(record.t_s)
        estimated += sum(1 for h in record.health.values() if h is Health.ESTIMATED)

    result = asyncio.run(run_simulation(config, on_tick=tick))
    z = next(a for a in result.summary if a.axis == AXIS)
    first = min((f["at_s"] for f in faults), default=None)
    degraded = (
        None
        if first is None
        else next(
            (t - first for t, good in zip(times, ok, strict=True) if t >= first and not good), None
        )
    )
    return Run(
        z.max_compensated_um, tuple(errors), tuple(ok), config.doc.period_s, degraded, estimated
    )


def cases(args: argparse.Namespace) -> dict[str, list[dict[str, Any]]]:
    """The cases ``--cases`` names, each fault moved to ``--at-s`` where given."""
    chosen: dict[str, list[dict[str, Any]]] = {}
    names = args.cases.split(",")
    if "issue33" in names or "all" in names:
        for signal in args.inputs.split(","):
            for kind in args.kinds.split(","):
                chosen[f"{signal} {kind}"] = [{"signal": signal, "at_s": AT_S, **KINDS[kind]}]
    if "issue41" in names or "all" in names:
        chosen |= ISSUE41
    for name in names:
        if name not in ("issue33", "issue41", "all"):
            if name not in ISSUE41:
                raise SystemExit(f"--cases: no case {name!r}; the cases: {', '.join(ISSUE41)}")
            chosen[name] = ISSUE41[name]
    if args.at_s is not None:
        chosen = {n: [f | {"at_s": args.at_s} for f in faults] for n, faults in chosen.items()}
    return chosen


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--cases",
        default="all",
        help="issue33, issue41, all, or issue 41 case names (comma-separated)",
    )
    parser.add_argument("--inputs", default=",".join(INPUTS), help="issue 33's cases: these inputs")
    parser.add_argument("--kinds", default=",".join(KINDS), help="issue 33's kinds, as printed")
    parser.add_argument("--seed", type=int, default=1, help="the scenario's seed (default 1)")
    parser.add_argument("--at-s", type=float, help="every case's faults start here (s) instead")
    parser.add_argument("--hours", type=float, default=6.0, help="the shift's length (default 6)")
    parser.add_argument(
        "--baseline", action="store_true", help="also run each without the plausibility check"
    )
    args = parser.parse_args()
    configure_logging(json_lines=False, level="ERROR")  # the figures on stdout, faults on stderr
    chosen = cases(args)
    free = run([], seed=args.seed, hours=args.hours)
    bound = BOUND_FACTOR * free.max_um
    print(
        f"production, seed {args.seed}, {args.hours:g} h: fault-free max |e| {free.max_um:.2f} um "
        f"(silent {free.silent_s(bound):.0f} s); the bound 3x: {bound:.2f} um; PASS: max <= bound "
        f"or silent <= {SILENT_LIMIT_S:.0f} s"
    )
    head = f"{'case':42s} {'max um':>8s} {'bound':>7s} {'silent':>8s} {'degraded':>9s} {'estimated':>10s}"
    print(head + (f" {'baseline':>9s}" if args.baseline else "") + "  verdict")
    failed = 0
    for name, faults in chosen.items():
        ours = run(faults, seed=args.seed, hours=args.hours)
        silent = ours.silent_s(bound)
        passed = ours.max_um <= bound or silent <= SILENT_LIMIT_S
        failed += not passed
        after = "never" if ours.degraded_after_s is None else f"{ours.degraded_after_s:.0f} s"
        line = (
            f"{name:42s} {ours.max_um:8.2f} {bound:7.2f} {silent:7.0f}s {after:>9s} "
            f"{ours.estimated:9d}s"
        )
        if args.baseline:
            line += f" {run(faults, seed=args.seed, hours=args.hours, baseline=True).max_um:9.2f}"
        print(line + ("  PASS" if passed else "  FAIL"), flush=True)
    print(f"{len(chosen) - failed} of {len(chosen)} cases pass issue 41's 'Done when'")


if __name__ == "__main__":
    main()
