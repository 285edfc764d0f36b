"""``compd twin``: a run of the simulated milling centre (the thermal twin) written as a data file.

The file has the columns every other command reads (``time_s``, controller
signals, ``T_*_degC`` temperatures, ``disp_*_um`` displacements), so
``compd fit``, ``compare`` and ``diagnose`` can be tried, and tested, on
runs whose physics is known: see :mod:`compd.sim`. The realistic runs
(``real_record``, ``real_calibration``, ``real_verify``) log ``T1`` ..
``T16`` instead, as a real machine's log often does.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import pandas as pd

from compd.cli.terminal import console
from compd.errors import CompdError
from compd.sim import SCENARIOS, simulate_scenario
from compd.sim.hall import air_conditioned
from compd.sim.positions import simulate_feed_positions
from compd.sim.realistic import REALISTIC_SCENARIOS
from compd.sim.variants import VARIANTS, machine_variant

#: Runs beyond the contract-column scenarios: extra columns (axis positions), or the realistic
#: runs' own (T1..T16 without locations, disp_x/y/z_um; see :mod:`compd.sim.realistic`).
EXTRA_SCENARIOS = {
    "feed_positions": "the feed run with X and Z dwelling at several positions; adds "
    "X_position_mm, Z_position_mm and the screw temperatures (Pahk 2002's position-dependent error)",
    **{name: text for name, (_, text) in REALISTIC_SCENARIOS.items()},
}

#: Decimals written per column kind: below each signal's noise, so nothing is lost.
_DECIMALS = {"T_": 4, "disp_": 3, "spindle_power_kw": 4, "feed_": 1}


def register(commands: Any) -> None:
    described = {**{name: text for name, (_, text) in SCENARIOS.items()}, **EXTRA_SCENARIOS}
    scenarios = "; ".join(f"{name}: {text}" for name, text in described.items())
    twin = commands.add_parser(
        "twin",
        help="generate a run of the simulated milling centre as a data file",
        description=f"Generate a logged run of the thermal twin. Scenarios: {scenarios}.",
    )
    scenario = twin.add_argument(
        "--scenario", required=True, metavar="NAME", help="one of: " + ", ".join(described)
    )
    # Offered by shell completion (compd.cli.topics); checked by the command, whose
    # message for a misspelt one lists them with what each is.
    scenario.completion_choices = list(described)
    twin.add_argument("--hours", type=float, required=True, help="length of the run, in h")
    twin.add_argument(
        "--out", type=Path, required=True, metavar="FILE.csv", help="CSV (or .parquet) to write"
    )
    twin.add_argument(
        "--seed", type=int, default=0, help="random seed: same seed, same run (default 0)"
    )
    twin.add_argument(
        "--sample-time-s", type=float, default=1.0, help="sample time, in s (default 1)"
    )
    twin.add_argument(
        "--variant",
        default="reference",
        choices=tuple(VARIANTS),
        help="machine configuration: "
        + "; ".join(f"{name}: {text}" for name, (_, text) in VARIANTS.items()),
    )
    twin.add_argument(
        "--air-conditioned",
        action="store_true",
        help="an air-conditioned hall: the ambient sensor also reads a 15 min +-0.4 degC AC "
        "cycle and 0.05 degC noise, which the structure does not feel (Swiss-lathe paper's noisy input)",
    )
    twin.set_defaults(handler=_twin)


def _twin(args: argparse.Namespace) -> int:
    options = {
        "seed": args.seed,
        "sample_time_s": args.sample_time_s,
        "params": machine_variant(args.variant),
    }
    if args.scenario in REALISTIC_SCENARIOS:
        if args.air_conditioned:
            raise CompdError(
                f"--air-conditioned applies to runs with a T_ambient_degC column; {args.scenario} "
                "has its own shop-floor sensors (T6, T7, T10): leave the option out"
            )
        frame = REALISTIC_SCENARIOS[args.scenario][0](args.hours, **options)
    elif args.scenario == "feed_positions":
        frame = simulate_feed_positions(args.hours, **options)
    else:
        frame = simulate_scenario(args.scenario, args.hours, **options)
    if args.air_conditioned:
        frame = air_conditioned(frame, args.seed)
    _write(_rounded(frame), args.out)
    out = console()
    disp = ", ".join(
        f"{name} {frame[name].min():.1f}..{frame[name].max():.1f}"
        for name in ("disp_x_um", "disp_y_um", "disp_z_um")
    )
    out.print(
        f"wrote {len(frame)} samples x {len(frame.columns) - 1} signals ({args.scenario}, "
        f"{args.hours:g} h at {args.sample_time_s:g} s, seed {args.seed}, {args.variant} machine) "
        f"to {args.out}; "
        f"displacement range (um): {disp}"
    )
    return 0


def _rounded(frame: pd.DataFrame) -> pd.DataFrame:
    decimals = {
        name: digits
        for name in frame.columns
        for prefix, digits in _DECIMALS.items()
        if name.startswith(prefix)
    }
    return frame.round(decimals)


def _write(frame: pd.DataFrame, path: Path) -> None:
    try:
        if path.suffix.lower() in (".parquet", ".pq"):
            frame.to_parquet(path, index=False)
        else:
            frame.to_csv(path, index=False)
    except (OSError, ImportError) as exc:
        raise CompdError(f"{path}: cannot write the run: {exc}") from None
