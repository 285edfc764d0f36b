"""The ``compd`` command line.

Each sub-command parses its options, calls one function of the library and
renders the result; errors from bad input end the command with exit status 2
and a one-paragraph message naming the file, the place and the fix.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Sequence
from importlib import resources
from pathlib import Path

import pandas as pd
from rich.console import Console
from rich.table import Column, Table

from compd import __version__
from compd.data import DataSet, load_data
from compd.errors import CompdError
from compd.evaluate import Evaluation, compare, evaluate
from compd.model.compiled import qualified_names
from compd.model.metrics import Comparison
from compd.modelfile import load_model

EXIT_INPUT_ERROR = 2


def main(argv: Sequence[str] | None = None) -> int:
    parser = _parser()
    args = parser.parse_args(argv)
    if not hasattr(args, "handler"):
        parser.print_help()
        return EXIT_INPUT_ERROR
    try:
        return int(args.handler(args) or 0)
    except CompdError as exc:
        print(f"compd: error: {exc}", file=sys.stderr)
        return EXIT_INPUT_ERROR


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="compd", description="Thermal-error compensation for CNC machine tools."
    )
    parser.add_argument("--version", action="version", version=f"compd {__version__}")
    commands = parser.add_subparsers(title="commands", metavar="COMMAND")

    demo = commands.add_parser(
        "demo", help="compare the bundled example models with bundled example data"
    )
    demo.set_defaults(handler=_demo)

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
    _data_options(sim)
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
    _data_options(cmp_)
    cmp_.set_defaults(handler=_compare)
    return parser


def _data_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--init",
        choices=("steady", "rest"),
        default="steady",
        help="initial model state: in equilibrium with the first sample (default) or all zero",
    )
    parser.add_argument(
        "--max-gap-s",
        type=float,
        default=60.0,
        help="longest run of missing samples to interpolate, in s (default 60)",
    )
    parser.add_argument(
        "--resample",
        action="store_true",
        help="interpolate irregularly sampled data onto a uniform grid instead of refusing it",
    )


def _load_data(args: argparse.Namespace) -> DataSet:
    return load_data(args.data, max_gap_s=args.max_gap_s, resample=args.resample)


def _console() -> Console:
    # Piped output (a file, a CI log) is read by people and grep alike:
    # don't wrap tables at rich's 80-column default.
    return Console(highlight=False, width=None if sys.stdout.isatty() else 200)


def _fmt(value: float, digits: int = 2) -> str:
    return "n/a" if math.isnan(value) else f"{value:.{digits}f}"


def _model_check(args: argparse.Namespace) -> int:
    model_file = load_model(args.model)
    compiled = model_file.compile(args.sample_time_s)
    console = _console()
    console.print(
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
    console.print(table)
    console.print("[green]ok[/green]: compiles, causal and stable")
    return 0


def _simulate(args: argparse.Namespace) -> int:
    evaluation = evaluate(load_model(args.model), _load_data(args), init=args.init)
    columns = {"time_s": evaluation.data.time_s}
    for i, name in enumerate(evaluation.compiled.output_names):
        columns[name] = evaluation.result.outputs[:, i]
    for i, name in enumerate(qualified_names(evaluation.compiled)):
        columns[name.replace("/", ".")] = evaluation.result.contributions[:, i]
    pd.DataFrame(columns).to_csv(args.out, index=False, float_format="%.6f")
    _print_notes(evaluation)
    print(f"wrote {len(evaluation.data)} samples x {len(columns) - 1} columns to {args.out}")
    return 0


def _compare(args: argparse.Namespace) -> int:
    evaluation = evaluate(load_model(args.model), _load_data(args), init=args.init)
    comparisons = compare(evaluation, args.output)
    if args.json:
        print(json.dumps(_compare_json(evaluation, comparisons), indent=2, allow_nan=False))
        return 0
    _print_notes(evaluation)
    _console().print(_comparison_table(evaluation, comparisons))
    return 0


def _compare_json(evaluation: Evaluation, comparisons: list[Comparison]) -> dict[str, object]:
    def clean(value: object) -> object:
        return None if isinstance(value, float) and math.isnan(value) else value

    return {
        "model": evaluation.compiled.name,
        "model_sha256": evaluation.model_file.sha256,
        "data": evaluation.data.path,
        "samples": len(evaluation.data),
        "sample_time_s": evaluation.data.sample_time_s,
        "notes": [*evaluation.data.notes, *evaluation.notes],
        "outputs": {
            c.output: {k: clean(v) for k, v in c.as_dict().items() if k != "output"}
            for c in comparisons
        },
    }


def _comparison_table(evaluation: Evaluation, comparisons: list[Comparison]) -> Table:
    data = evaluation.data
    table = Table(
        "output",
        "fit %",
        "residue RMS",
        "residue p-p",
        "max |residue|",
        "uncomp. RMS",
        "uncomp. p-p",
        "RMS reduction",
        "p-p reduction",
        title=f"{evaluation.compiled.name} vs {data.path} ({len(data)} samples, "
        f"{data.sample_time_s:g} s, {data.time_s[-1] / 3600:.2f} h); errors in um",
    )
    for c in comparisons:
        table.add_row(
            c.output,
            _fmt(c.fit_percent, 1),
            _fmt(c.residue.rms_um),
            _fmt(c.residue.peak_to_peak_um),
            _fmt(c.residue.max_abs_um),
            _fmt(c.uncompensated.rms_um),
            _fmt(c.uncompensated.peak_to_peak_um),
            f"{_fmt(c.rms_reduction_percent, 1)} %",
            f"{_fmt(c.peak_to_peak_reduction_percent, 1)} %",
        )
    return table


def _print_notes(evaluation: Evaluation) -> None:
    for note in (*evaluation.data.notes, *evaluation.notes):
        print(f"note: {note}", file=sys.stderr)


def _demo(args: argparse.Namespace) -> int:
    """The bundled default: seed 000's TF model against the controller's regression, and a gated ARX model."""
    bundled = resources.files("compd.bundled")
    with resources.as_file(bundled / "example_spectrum.csv") as data_path:
        data = load_data(data_path)
    console = _console()
    console.print(
        f"[bold]compd {__version__} demo[/bold]: an 8-hour SPECTRUM-style test (spindle speed steps, "
        "then cooling) on a milling centre, bundled as example_spectrum.csv.\n"
    )
    rows: list[tuple[str, Comparison]] = []
    for name in ("seed000_hmc_tf.yaml", "seed000_linear_regression.yaml", "example_gated_arx.yaml"):
        with resources.as_file(bundled / name) as model_path:
            evaluation = evaluate(load_model(model_path), data)
        comparisons = compare(evaluation)
        console.print(_comparison_table(evaluation, comparisons))
        rows.extend((evaluation.compiled.name, c) for c in comparisons)
    tf_z = next(c for name, c in rows if name == "seed000-hmc-z")
    lr_z = next(c for name, c in rows if name == "seed000-controller-linear-regression")
    console.print(
        f"\nz axis: the transfer-function model leaves {tf_z.residue.rms_um:.1f} um RMS of "
        f"{tf_z.uncompensated.rms_um:.1f} um; the controller's linear regression leaves "
        f"{lr_z.residue.rms_um:.1f} um. Try: compd model check / simulate / compare (compd --help)."
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
