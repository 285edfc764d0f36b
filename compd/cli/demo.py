"""``compd demo``: the bundled example models compared with bundled example data."""

from __future__ import annotations

import argparse
from importlib import resources
from typing import Any

from compd import __version__
from compd.cli.common import comparison_table
from compd.cli.terminal import Text, console
from compd.files.data import load_data
from compd.files.modelfile import load_model
from compd.model.metrics import Comparison
from compd.toolkit.evaluate import compare, evaluate


def register(commands: Any) -> None:
    demo = commands.add_parser(
        "demo",
        help="compare the bundled example models with bundled example data",
        description="Compare the bundled example models (a transfer-function model after "
        "Horejs 2010, the controller's linear regression and a gated ARX model) with a bundled "
        "8-hour test record: fit, residue and the reduction compensation would give. Nothing "
        "to configure: a first look at what compd measures.",
    )
    demo.set_defaults(handler=_demo)


def _demo(args: argparse.Namespace) -> int:
    """The bundled default: Horejs 2010's TF model against the controller's regression, and a gated ARX model."""
    bundled = resources.files("compd.bundled")
    with resources.as_file(bundled / "example_spectrum.csv") as data_path:
        data = load_data(data_path)
    out = console()
    out.print(
        Text.assemble(
            (f"compd {__version__} demo", "bold"),
            ": an 8-hour SPECTRUM-style test (spindle speed steps, "
            "then cooling) on a milling centre, bundled as example_spectrum.csv.\n",
        )
    )
    rows: list[tuple[str, Comparison]] = []
    for name in ("seed000_hmc_tf.yaml", "seed000_linear_regression.yaml", "example_gated_arx.yaml"):
        with resources.as_file(bundled / name) as model_path:
            evaluation = evaluate(load_model(model_path), data)
        comparisons = compare(evaluation)
        out.print(comparison_table(evaluation, comparisons))
        rows.extend((evaluation.compiled.name, c) for c in comparisons)
    tf_z = next(c for name, c in rows if name == "seed000-hmc-z")
    lr_z = next(c for name, c in rows if name == "seed000-controller-linear-regression")
    out.print(
        f"\nz axis: the transfer-function model leaves {tf_z.residue.rms_um:.1f} um RMS of "
        f"{tf_z.uncompensated.rms_um:.1f} um; the controller's linear regression leaves "
        f"{lr_z.residue.rms_um:.1f} um. Try: compd model check / simulate / compare (compd --help)."
    )
    return 0
