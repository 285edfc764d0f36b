"""``compd model check`` and ``compd model load``: one model file, checked or put into service."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from compd.cli.args import daemon_options


def register(commands: Any) -> None:
    model = commands.add_parser(
        "model", help="model files: check one, load one into the running daemon"
    ).add_subparsers(metavar="ACTION")
    check = model.add_parser("check", help="validate and compile a model file; show its sub-models")
    check.add_argument("model", type=Path, metavar="MODEL.yaml")
    check.add_argument(
        "--sample-time-s", type=float, help="compile for this sample time (default: the model's)"
    )
    check.set_defaults(handler=_check)
    load = model.add_parser(
        "load", help="validate, install and switch the running daemon to a model file"
    )
    load.add_argument("model", type=Path, metavar="MODEL.yaml")
    daemon_options(load)
    load.set_defaults(handler=_load)


def _check(args: argparse.Namespace) -> int:
    from rich.table import Column, Table

    from compd.cli.terminal import console
    from compd.files.modelfile import load_model
    from compd.model.compiled import qualified_names

    model_file = load_model(args.model)
    compiled = model_file.compile(args.sample_time_s)
    warnings = model_file.check_plausible()
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
        "gate, position",
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
            sub.describe_factors(),
        )
    out.print(table)
    for finding in warnings:
        print(finding.describe(), file=sys.stderr)
    out.print("[green]ok[/green]: compiles, causal and stable")
    return 0


def _load(args: argparse.Namespace) -> int:
    from compd.cli.daemon import model_load_command

    return model_load_command(args)
