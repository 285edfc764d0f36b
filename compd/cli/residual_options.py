"""``compd fit --residual-model SIGNAL``: Swiss-lathe paper's door residual forest on top of the fitted TF model.

Kept apart from :mod:`compd.cli.fit` so that command only declares the
options and hands over the writing: without ``--residual-model`` the model
file is written as before; with it the forest's ``.npz`` sidecar is written
first, then the YAML that names it by sha256, and the TF-alone vs stacked
residue (peak-to-peak and RMS, Swiss-lathe paper, tables 2-5) is printed.
"""

from __future__ import annotations

import argparse
from typing import Any

from rich.table import Table

from compd.cli.terminal import console
from compd.files.data import DataSet
from compd.files.provenancepaths import write_model_text
from compd.files.sidecar import sidecar_path
from compd.toolkit.fit import FitResult
from compd.toolkit.residual import stack_residual
from compd.toolkit.span import Span
from compd.toolkit.summary import fmt


def add_residual_options(parser: Any) -> None:
    """The ``--residual-model``, ``--trees``, ``--max-depth`` and ``--forest-seed`` options of ``compd fit``."""
    parser.add_argument(
        "--residual-model",
        metavar="DOOR_SIGNAL",
        help="stack a random forest on the TF model's residue, fed the door signal smoothed at "
        "several time scales (Swiss-lathe paper); the calibration data must contain door openings",
    )
    add_forest_options(parser)


def add_forest_options(parser: Any) -> None:
    """``--trees``, ``--max-depth`` and ``--forest-seed``: the forest's size and seed."""
    parser.add_argument(
        "--trees", type=int, default=100, metavar="N", help="forest size (default 100)"
    )
    parser.add_argument(
        "--max-depth", type=int, default=10, metavar="D", help="tree depth limit (default 10)"
    )
    parser.add_argument(
        "--forest-seed", type=int, default=0, metavar="N", help="forest random seed (default 0)"
    )


def write_fit(
    result: FitResult, data: DataSet, args: argparse.Namespace, span: Span | None = None
) -> None:
    """Write the model file (and with ``--residual-model`` its sidecar first), then report.

    ``span`` (``--from``/``--until``): the forest is fitted on the samples the TFs were.
    """
    if not getattr(args, "residual_model", None):
        write_model_text(args.out, result.yaml_text)
        return
    stacked = stack_residual(
        result,
        data,
        args.out,
        signal=args.residual_model,
        trees=args.trees,
        max_depth=args.max_depth,
        seed=args.forest_seed,
        span=span,
    )
    sidecar_path(args.out).write_bytes(stacked.sidecar)
    write_model_text(args.out, stacked.yaml_text)
    forest = stacked.fit.residual.forest
    table = Table(
        "on the calibration data",
        "peak-to-peak (um)",
        "RMS (um)",
        title=f"residual model on {args.residual_model}: {forest.n_trees} trees, "
        f"depth {forest.depth}, {forest.n_nodes} nodes in {stacked.sidecar_name}",
    )
    for label, figures in (("TF alone", stacked.fit.tf_alone), ("stacked", stacked.fit.stacked)):
        table.add_row(label, fmt(figures.peak_to_peak_um, 3), fmt(figures.rms_um, 3))
    console().print(table)
