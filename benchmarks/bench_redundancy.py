"""A failing sensor beside its second one: the compensated error with and without the redundant pair.

Each run: the bundled config and model (``bundled:simulated.yaml``, whose
spindle and air sensors each have a second sensor beside them), a shift of
the simulated machine (default: production, 6 h, seed 1, compd on virtual
time in this process), one fault on one sensor. Kinds (issue 41): a drift
(chained ``offset`` faults, 0.1 degC more every 180 s for 2 degC/h, 360 s for
1 degC/h, 720 s for 0.5 degC/h) for 4 h from 1 h; a plausible wrong value
(+8 degC, 1 h from 2 h); a freeze (4 h from 2 h).

Printed per case: the compensated max error (um) with the pair (what ships)
and without it (the same config with no ``redundant:`` keys), how long the
status was not OK while the error exceeded 3x the fault-free run's, how many
seconds after the fault started the pair flagged it, and the pair episodes.
Also, for fault-free shifts (``--free``): the pair episodes and the time not
OK, which should both be 0.

``--replay`` runs the pair check alone (no daemon) over 12 fault-free 8 h
shifts of the twin's sensors: the lag difference it learnt, the largest
excess and CUSUM value, the episodes (0).

Run: ``python benchmarks/bench_redundancy.py [--cases A,B] [--single A] [--free] [--replay]
[--scenario S --hours H --seed N]`` (about 30 s a run on an idle machine).
"""

from __future__ import annotations

import argparse
import asyncio
import sys
from pathlib import Path
from typing import Any

import yaml

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from simconfig import bundled_doc  # noqa: E402

from compd.cli.serving import configure_logging  # noqa: E402
from compd.service.config.loading import load_config  # noqa: E402
from compd.sim.plc.run import run_simulation  # noqa: E402

PAIRED = ("T_spindle_degC", "T_ambient_degC")


def drift(signal: str, degc_per_h: float, at_s: float = 3600.0, hours: float = 4.0) -> list[dict]:
    """A drift as chained ``offset`` faults: 0.1 degC more every ``360 / degc_per_h`` s."""
    step_s = 360.0 / degc_per_h
    n = round(hours * 3600 / step_s)
    return [
        {
            "kind": "offset",
            "signal": signal,
            "at_s": at_s + i * step_s,
            "duration_s": step_s,
            "value": round(0.1 * (i + 1), 6),
        }
        for i in range(n)
    ]


CASES: dict[str, list[dict[str, Any]]] = {
    "spindle drift +2/h": drift("T_spindle_degC", 2.0),
    "spindle drift +0.5/h": drift("T_spindle_degC", 0.5),
    "spindle offset +8": [
        {"kind": "offset", "signal": "T_spindle_degC", "at_s": 7200, "duration_s": 3600, "value": 8}
    ],
    "spindle freeze 4 h": [
        {"kind": "stuck", "signal": "T_spindle_degC", "at_s": 7200, "duration_s": 4 * 3600 - 1}
    ],
    "air drift +1/h": drift("T_ambient_degC", 1.0),
    "air offset +3": [
        {"kind": "offset", "signal": "T_ambient_degC", "at_s": 7200, "duration_s": 3600, "value": 3}
    ],
    "partner drift -2/h": [f | {"value": -f["value"]} for f in drift("T_spindle_b_degC", 2.0)],
}


def run(
    faults: list[dict[str, Any]], *, paired: bool, scenario: str, hours: float, seed: int
) -> dict[str, Any]:
    """One shift: max compensated error (um), records, counters."""
    directory, doc = bundled_doc("bench-red-")
    doc["simulation"] = {"scenario": scenario, "hours": hours, "seed": seed, "faults": faults}
    if not paired:
        for name in PAIRED:
            doc["signals"][name].pop("redundant", None)
    (directory / "c.yaml").write_text(yaml.safe_dump(doc))
    records: list[Any] = []
    machine_truth: list[float] = []

    def on_tick(snapshot: Any, machine: Any, record: Any) -> None:
        records.append(record)
        machine_truth.append(machine.truth_now()["Z"][2])

    result = asyncio.run(run_simulation(load_config(directory / "c.yaml"), on_tick=on_tick))
    z = next(a for a in result.summary if a.axis == "Z")
    return {
        "max_um": z.max_compensated_um,
        "records": records,
        "errors_um": machine_truth,
        "pair_faults": result.status["counters"].get("redundancy_faults", 0),
    }


def replay(scenarios: list[str], seeds: list[int], hours: float) -> None:
    """The pair check alone over fault-free shifts of the twin's sensors (no daemon: seconds a shift).

    Per shift and pair: the learnt lag difference (s), the largest excess once
    learnt (degC; the tolerance is 0.5), the CUSUM's largest value (its decision
    interval is 30) and the episodes (should be 0).
    """
    import numpy as np

    from compd.service.loop.redundancy import Pair, PairCheck
    from compd.service.loop.signals import Checks, Health, Reading, SignalMonitor
    from compd.sim.partners import PARTNER_OF, PartnerBank
    from compd.sim.scenarios import scenario_inputs
    from compd.sim.sensors import SensorBank, SensorSet
    from compd.sim.thermal import MachineInputs, MachineTwin

    for scenario in scenarios:
        for seed in seeds:
            inputs = scenario_inputs(scenario, hours, seed, 1.0)
            first = MachineInputs(float(inputs.T_ambient_degC[0]), float(inputs.T_coolant_degC[0]))
            twin = MachineTwin(first, sample_time_s=1.0)
            rng = np.random.default_rng([seed, 1])  # as the simulated machine draws them
            bank = SensorBank(SensorSet.draw(rng), 1.0, rng)
            partners = PartnerBank(1.0, np.random.default_rng([seed, 3]))
            names = [*PARTNER_OF, *PARTNER_OF.values()]
            monitors = {n: SignalMonitor(n, Checks()) for n in names}
            checks = {
                b: PairCheck(Pair(a, b, 0.5, "degC"), monitors, 1.0) for b, a in PARTNER_OF.items()
            }
            worst = dict.fromkeys(PARTNER_OF, 0.0)
            cusum = dict.fromkeys(PARTNER_OF, 0.0)
            state = twin.state
            for k in range(len(inputs) - 1):
                u = inputs.at(k)
                row, second = bank.read(state, u), partners.read(state, u)
                for b, a in PARTNER_OF.items():
                    c = checks[b]
                    c.update(k, Reading(row[a], Health.OK), Reading(second[b], Health.OK), row[a])
                    if not np.isnan(c.excess):
                        worst[b] = max(worst[b], abs(c.excess))
                    cusum[b] = max(cusum[b], c.cusum_high, c.cusum_low)
                state = twin.step(u)
            print(
                f"{scenario:10s} seed {seed}: "
                + "; ".join(
                    f"{a} lag {checks[b].difference.lag_s:+.1f} s, max excess {worst[b]:.3f}, "
                    f"CUSUM {cusum[b]:.1f}, episodes {checks[b].fault.episodes}"
                    for b, a in PARTNER_OF.items()
                ),
                flush=True,
            )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default=",".join(CASES), help="comma-separated, as printed")
    parser.add_argument("--free", action="store_true", help="fault-free shifts only")
    parser.add_argument("--scenario", default="production")
    parser.add_argument("--hours", type=float, default=6.0)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument(
        "--single", default=None, help="cases also run without the pair (default: all)"
    )
    parser.add_argument(
        "--later-s", type=float, default=0.0, help="every fault this much later (s): another start"
    )
    parser.add_argument(
        "--replay",
        action="store_true",
        help="the pair check alone over 12 fault-free 8 h shifts (6 scenarios, seeds 1 and 2)",
    )
    args = parser.parse_args()
    configure_logging(json_lines=False, level="ERROR")  # the figures on stdout, faults on stderr
    if args.replay:
        scenarios = ["production", "cutting", "door", "coolant", "feed", "shift"]
        replay(scenarios, [1, 2], 8.0)
        return
    shift = {"scenario": args.scenario, "hours": args.hours, "seed": args.seed}
    free = run([], paired=True, **shift)
    not_ok = sum(1 for r in free["records"] if r.status & 0b11)
    print(
        f"{args.scenario} {args.hours:g} h seed {args.seed}: fault-free max {free['max_um']:.2f} um, "
        f"pair episodes {free['pair_faults']}, ticks not OK {not_ok}",
        flush=True,
    )
    if args.free:
        return
    bound = 3 * free["max_um"]
    print(f"the issue's bound 3x: {bound:.2f} um")
    print(
        f"{'case':22s} {'paired':>8s} {'single':>8s} {'silent>3x':>10s} {'flagged':>9s} {'episodes':>9s}"
    )
    for name in args.cases.split(","):
        faults = [f | {"at_s": f["at_s"] + args.later_s} for f in CASES[name]]
        ours = run(faults, paired=True, **shift)
        singles = args.cases if args.single is None else args.single
        single = run(faults, paired=False, **shift) if name in singles.split(",") else None
        start = min(f["at_s"] for f in faults)
        silent = sum(
            1
            for r, e in zip(ours["records"], ours["errors_um"], strict=True)
            if abs(e) > bound and not r.status & 0b11
        )
        flagged = next(
            (r.t_s - start for r in ours["records"] if r.t_s >= start and r.status & 0b11), None
        )
        after = "never" if flagged is None else f"{flagged:.0f} s"
        print(
            f"{name:22s} {ours['max_um']:8.2f} "
            f"{'-' if single is None else format(single['max_um'], '.2f'):>8s} {silent:9d}s {after:>9s} "
            f"{ours['pair_faults']:9d}",
            flush=True,
        )


if __name__ == "__main__":
    main()
