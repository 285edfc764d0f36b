"""``compd residual``: stack Swiss-lathe paper's door residual forest on an existing model, TF alone vs stacked.

Swiss-lathe paper keeps its calibrated ARX model and adds a random forest fitted on
that model's residue against the smoothed door signal. This is that step for
any compd model file: the sub-models are kept, the forest is fitted on the
free-run residue over DATA.csv (the one ``compd compare`` shows), the
sidecar ``.npz`` and the new model file are written, and the residue's
peak-to-peak and RMS are printed for the model alone and stacked, on
DATA.csv and, with ``--verify``, on a record not used for fitting (both
figures from the written files, as ``compd compare`` would give them).
``compd fit --residual-model`` does the same right after fitting the TFs.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from rich.table import Table

from compd.cli.common import data_options, load_data_from_args, span_from_args
from compd.cli.residual_options import add_forest_options
from compd.cli.terminal import console
from compd.files.data import DataSet
from compd.files.modelfile import ModelFile, load_model
from compd.files.provenancepaths import write_model_text
from compd.files.sidecar import sidecar_path
from compd.toolkit.evaluate import evaluate, measured_columns
from compd.toolkit.residual import ResidueFigures, stack_on_model
from compd.toolkit.span import Span, evaluate_span
from compd.toolkit.summary import fmt, json_text


def register(commands: Any) -> None:
    parser = commands.add_parser(
        "residual",
        help="stack a random forest on a model's residue against the smoothed door signal "
        "(Swiss-lathe paper) and show the residue before and after",
    )
    parser.add_argument("model", type=Path, metavar="MODEL.yaml")
    parser.add_argument(
        "data",
        type=Path,
        nargs="+",
        metavar="DATA",
        help="a record with door openings: a file, or the files (a folder) of one recorded run",
    )
    parser.add_argument(
        "--signal", default="door_open", help="the door status column (default door_open)"
    )
    parser.add_argument("--out", type=Path, required=True, metavar="NEW.yaml")
    parser.add_argument(
        "--output", metavar="COLUMN", help="the measured column, when the model has several outputs"
    )
    add_forest_options(parser)
    parser.add_argument(
        "--verify", type=Path, metavar="OTHER.csv", help="also judge both on this record"
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    data_options(
        parser,
        initial_state=False,
        scored="fitted and judged (the forest's door features, like the model, run from the "
        "file's start)",
    )
    parser.set_defaults(handler=_residual)


def _figures(
    model_file: ModelFile, data: DataSet, column: str | None, span: Span | None = None
) -> ResidueFigures:
    evaluation = (
        evaluate(model_file, data) if span is None else evaluate_span(model_file, data, span)
    )
    ((predicted, measured),) = measured_columns(evaluation, column).items()
    return ResidueFigures.of(evaluation.data.column(measured) - evaluation.predicted(predicted))


def _residual(args: argparse.Namespace) -> int:
    parent = load_model(args.model)
    data = load_data_from_args(args)
    span = span_from_args(args, data)
    for note in data.notes:  # what was joined, repaired or left out
        print(f"note: {note}", file=sys.stderr)
    verify = load_data_from_args(args, args.verify) if args.verify else None
    stacked = stack_on_model(
        parent,
        data,
        args.out,
        signal=args.signal,
        output=args.output,
        trees=args.trees,
        max_depth=args.max_depth,
        seed=args.forest_seed,
        span=span,
    )
    sidecar_path(args.out).write_bytes(stacked.sidecar)
    write_model_text(
        args.out, stacked.yaml_text, parent=parent.doc.provenance, parent_path=Path(parent.path)
    )
    written = load_model(args.out)  # the figures are those of the files as written
    records = [("data", data)] + ([("verify", verify)] if verify is not None else [])
    spans = {"data": span, "verify": None}
    figures = {
        label: (
            _figures(parent, record, args.output, spans[label]),
            _figures(written, record, args.output, spans[label]),
        )
        for label, record in records
    }
    if args.json:
        summary = {
            "model": str(args.model),
            "out": str(args.out),
            "sidecar": stacked.sidecar_name,
            "signal": args.signal,
            **{
                label: {
                    "path": str(record.path),
                    "model_alone": vars(figures[label][0]),
                    "stacked": vars(figures[label][1]),
                }
                for label, record in records
            },
            **span.json(),
        }
        print(json_text(summary))
        return 0
    forest = stacked.fit.residual.forest
    table = Table(
        "record",
        "p-p alone (um)",
        "p-p stacked (um)",
        "RMS alone (um)",
        "RMS stacked (um)",
        title=f"residue of {args.model} alone and with the {args.signal} forest ({forest.n_trees} "
        f"trees, depth {forest.depth})",
    )
    for label, record in records:
        alone, both = figures[label]
        name = str(record.path) + (" (not used for fitting)" if label == "verify" else "")
        table.add_row(
            name,
            fmt(alone.peak_to_peak_um, 2),
            fmt(both.peak_to_peak_um, 2),
            fmt(alone.rms_um, 3),
            fmt(both.rms_um, 3),
        )
    out = console()
    out.print(table)
    if not span.whole:
        out.print(span.describe("fitted and judged"))
    out.print(f"wrote {args.out} and {stacked.sidecar_name}")
    return 0
