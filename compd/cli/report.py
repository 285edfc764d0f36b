"""``compd report``: one self-contained HTML file of a model (or two) on a data file."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from compd.cli.common import (
    data_options,
    load_experiments_from_args,
    refuse_with_several,
    span_from_args,
    window_options,
)
from compd.cli.probes import probe_options, probe_runs, refuse_several_records, wants_probes
from compd.files.experiments import stack
from compd.files.modelfile import load_model
from compd.toolkit.evaluate import Evaluation, evaluate_each
from compd.toolkit.span import evaluate_span


def register(commands: Any) -> None:
    report = commands.add_parser(
        "report",
        help="one HTML file: measured vs simulated, residue, failing windows, contributions, "
        "candidates, conditions",
    )
    report.add_argument("model", type=Path, metavar="MODEL.yaml")
    report.add_argument(
        "data",
        type=Path,
        nargs="+",
        metavar="DATA",
        help="a data file, the files (a folder) of one recorded run, or several experiments "
        "(separate runs): drawn end to end, each run from its own start",
    )
    report.add_argument("--out", type=Path, required=True, metavar="REPORT.html")
    report.add_argument(
        "--compare",
        type=Path,
        metavar="OTHER.yaml",
        help="a second model on the same data, shown side by side with the change in each figure",
    )
    window_options(report)
    data_options(report, scored="shown and judged")
    probe_options(report)  # the first model's probe updates: a section per output
    report.set_defaults(handler=_report)


def _report(args: argparse.Namespace) -> int:
    # plotly is imported only by the command that draws: every other command
    # (and the 1 Hz service) starts without it.
    from compd.report import write_report

    experiments = load_experiments_from_args(args)
    refuse_with_several(
        experiments, {"--from": args.from_s is not None, "--until": args.until_s is not None}
    )
    if wants_probes(args):
        refuse_several_records(experiments)
    several = stack(experiments) if len(experiments) > 1 else None
    data = experiments[0] if several is None else several.data
    span = span_from_args(args, data)

    def run(model: Path) -> Evaluation:
        """One record (its span), or several files end to end, each run from its own start."""
        if several is None:
            return evaluate_span(load_model(model), data, span, init=args.init)
        return evaluate_each(load_model(model), several, init=args.init)

    evaluation = run(args.model)
    other = None if args.compare is None else run(args.compare)
    probes = probe_runs(args, evaluation) if wants_probes(args) else []
    path = write_report(
        args.out,
        evaluation,
        other=other,
        column=args.output,
        tolerance_um=args.tolerance_um,
        window_s=args.window_s,
        probes=probes,
    )
    notes = [*data.notes, *evaluation.notes, *(other.notes if other is not None else ())]
    for note in dict.fromkeys(notes):
        print(f"note: {note}", file=sys.stderr)
    if not span.whole:
        print(span.describe("shown and judged"))
    print(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB)")
    return 0
