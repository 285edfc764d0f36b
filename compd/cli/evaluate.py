"""``compd model check``, ``compd simulate`` and ``compd compare``: a model file over a data file."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import pandas as pd
from rich.table import Column, Table

from compd.cli.common import (
    compare_json,
    comparison_table,
    console,
    data_options,
    load_data_from_args,
    print_notes,
)
from compd.evaluate import compare, evaluate
from compd.model.compiled import qualified_names
from compd.modelfile import load_model


def register(commands: Any) -> None:
    model = commands.add_parser("model", help="model files").add_subparsers(metavar="ACTION")
    check = model.add_parser("check", help="validate and compile a model file; show its sub-models")
    check.add_argument("model", type=Path, metavar="MODEL.yaml")
    check.add_argument(
        "--sample-time-s", type=float, help="compile for this sample time (default: the model's)"
    )
    check.set_defaults(handler=_model_check)

    sim = commands.add_parser(
        "simulate", help="model output and each sub-model's contribution per sample"
    )
    sim.add_argument("model", type=Path, metavar="MODEL.yaml")
    sim.add_argument("data", type=Path, metavar="DATA.csv")
    sim.add_argument("--out", type=Path, required=True, metavar="PRED.csv")
    data_options(sim)
    sim.set_defaults(handler=_simulate)

    cmp_ = commands.add_parser(
        "compare", help="model against measurement: fit %%, residue, reduction"
    )
    cmp_.add_argument("model", type=Path, metavar="MODEL.yaml")
    cmp_.add_argument("data", type=Path, metavar="DATA.csv")
    cmp_.add_argument(
        "--output",
        metavar="COLUMN",
        help="measured column to compare (default: columns named like the model's outputs)",
    )
    cmp_.add_argument(
        "--json", action="store_true", help="print one JSON object instead of a table"
    )
    data_options(cmp_)
    cmp_.set_defaults(handler=_compare)


def _model_check(args: argparse.Namespace) -> int:
    model_file = load_model(args.model)
    compiled = model_file.compile(args.sample_time_s)
    out = console()
    out.print(
        f"[bold]{compiled.name}[/bold]  {model_file.path}  sha256 {model_file.sha256[:12]}  "
        f"sample time {compiled.sample_time_s:g} s  signals: {', '.join(compiled.signals)}"
    )
    table = Table(
        "effect",
        "input",
        "order",
        "nk",
        "poles (z)",
        "time constants (s)",
        "static gain (um/unit)",
        "gain",
        "gate",
    )
    table.columns.insert(0, Column("sub-model", no_wrap=True))
    for name, sub, tf in zip(
        qualified_names(compiled), compiled.submodels, compiled.discrete, strict=True
    ):
        table.add_row(
            name,
            sub.effect,
            sub.input.describe(),
            str(tf.order),
            str(tf.nk),
            ", ".join(f"{p:.6g}" for p in tf.poles()) or "-",
            ", ".join(f"{t:.1f}" for t in tf.time_constants_s(compiled.sample_time_s)) or "-",
            f"{tf.static_gain():.4g}",
            f"{sub.gain:g}",
            sub.gate.describe() if sub.gate else "always",
        )
    out.print(table)
    out.print("[green]ok[/green]: compiles, causal and stable")
    return 0


def _simulate(args: argparse.Namespace) -> int:
    evaluation = evaluate(load_model(args.model), load_data_from_args(args), init=args.init)
    columns = {"time_s": evaluation.data.time_s}
    for i, name in enumerate(evaluation.compiled.output_names):
        columns[name] = evaluation.result.outputs[:, i]
    for i, name in enumerate(qualified_names(evaluation.compiled)):
        columns[name.replace("/", ".")] = evaluation.result.contributions[:, i]
    pd.DataFrame(columns).to_csv(args.out, index=False, float_format="%.6f")
    print_notes(evaluation)
    print(f"wrote {len(evaluation.data)} samples x {len(columns) - 1} columns to {args.out}")
    return 0


def _compare(args: argparse.Namespace) -> int:
    evaluation = evaluate(load_model(args.model), load_data_from_args(args), init=args.init)
    comparisons = compare(evaluation, args.output)
    if args.json:
        print(json.dumps(compare_json(evaluation, comparisons), indent=2, allow_nan=False))
        return 0
    print_notes(evaluation)
    console().print(comparison_table(evaluation, comparisons))
    return 0
