"""Fault-free shifts of the bundled simulated machine: nothing is replaced, nothing flagged, the status OK.

The other half of "never silently wrong" (issue 41): a check that cries wolf
is switched off by the shop. Each run: the bundled config and model
(``bundled:simulated.yaml``, its redundant pairs included), an 8 h shift of
one scenario (production, cutting, door, coolant, feed, shift) and seed (1,
2), no fault, compd on virtual time in this process.

Printed per run: the compensated max |error| on Z (um); the seconds the status
word was not OK after the first minute (``status & 0b11``); the stand-in
episodes begun (sensors replaced by their prediction) and how many of them
were drifts; the redundant pairs' fault episodes; the envelope's fault
episodes. Every count should be 0; the last line says whether all were.

Run: ``python benchmarks/bench_fault_free.py [--scenarios A,B] [--seeds 1,2] [--hours 8]``
(about 40 s a run on a quiet machine).
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

SCENARIOS = ("production", "cutting", "door", "coolant", "feed", "shift")
#: The first minute is the start (the model warming, the slew from zero): not judged.
SETTLE_S = 60.0
LEVEL_BITS = 0b11


def run(scenario: str, seed: int, hours: float) -> dict[str, Any]:
    directory, doc = bundled_doc("bench-ff-")
    doc["simulation"] = {"scenario": scenario, "hours": hours, "seed": seed}
    (directory / "c.yaml").write_text(yaml.safe_dump(doc))
    not_ok = [0]
    services: list[Any] = []

    def on_tick(service: Any, machine: Any, record: Any) -> None:
        if not services:
            services.append(service)
        if record.t_s >= SETTLE_S and record.status & LEVEL_BITS:
            not_ok[0] += 1

    result = asyncio.run(run_simulation(load_config(directory / "c.yaml"), on_tick=on_tick))
    compensator = services[0].compensator
    plausibility = compensator.plausibility
    counters = compensator.counters
    z = next(a for a in result.summary if a.axis == "Z")
    return {
        "max_um": z.max_compensated_um,
        "not_ok_s": not_ok[0] * doc["period_s"],
        "stand_ins": 0 if plausibility is None else plausibility.count,
        "drifts": 0 if plausibility is None else plausibility.drifts,
        "pair_faults": getattr(counters, "redundancy_faults", 0),
        "envelope_faults": getattr(counters, "envelope_faults", 0),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenarios", default=",".join(SCENARIOS))
    parser.add_argument("--seeds", default="1,2")
    parser.add_argument("--hours", type=float, default=8.0)
    args = parser.parse_args()
    configure_logging(json_lines=False, level="ERROR")  # figures on stdout, faults on stderr
    print(
        f"{'scenario':11s} {'seed':>4s} {'max um':>7s} {'not OK s':>9s} {'stand-ins':>9s} "
        f"{'drifts':>6s} {'pair faults':>11s} {'envelope':>8s}"
    )
    clean = True
    for seed in (int(s) for s in args.seeds.split(",")):
        for scenario in args.scenarios.split(","):
            r = run(scenario, seed, args.hours)
            counts = (
                r["not_ok_s"],
                r["stand_ins"],
                r["drifts"],
                r["pair_faults"],
                r["envelope_faults"],
            )
            clean &= not any(counts)
            print(
                f"{scenario:11s} {seed:4d} {r['max_um']:7.2f} {r['not_ok_s']:9.0f} {r['stand_ins']:9d} "
                f"{r['drifts']:6d} {r['pair_faults']:11d} {r['envelope_faults']:8d}",
                flush=True,
            )
    print("all fault-free shifts clean" if clean else "NOT CLEAN: see the counts above")


if __name__ == "__main__":
    main()
