"""``compd extend``: add the missing effect to a model as a new sub-model, and show the error fall."""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path
from typing import Any

from rich.table import Table
from rich.text import Text

from compd.cli.common import data_options, load_data_from_args, order_arg, span_from_args
from compd.cli.progress import progress_reporter
from compd.cli.terminal import console
from compd.files.effects import load_catalogue
from compd.files.modelfile import load_model
from compd.files.provenancepaths import write_model_text
from compd.model.identify import MIN_SAMPLES
from compd.model.transfer import DiscreteTF
from compd.toolkit.extend import extend_model, verify_extension, with_verification
from compd.toolkit.summary import fmt, json_clean, json_text


def register(commands: Any) -> None:
    extend = commands.add_parser(
        "extend",
        help="identify a sub-model from an effect's signal to the residue and add it (seed 001 4.3)",
    )
    extend.add_argument("model", type=Path, metavar="MODEL.yaml")
    extend.add_argument("data", type=Path, metavar="DATA.csv", help="a record with the effect")
    extend.add_argument(
        "--effect", required=True, metavar="SIGNAL", help="the excitation: a column of DATA.csv"
    )
    extend.add_argument("--out", type=Path, required=True, metavar="NEW.yaml")
    extend.add_argument(
        "--order",
        type=order_arg,
        default="auto",
        help="TF order of the new sub-model: 'auto' (chosen on held-back data) or N",
    )
    extend.add_argument(
        "--method",
        choices=("oe", "arx", "lagbank"),
        default="oe",
        help="identification method (default oe); lagbank: first-order lags at fixed time "
        "constants, ridge-regularised, as the held-out check fits them (one sub-model per lag)",
    )
    extend.add_argument(
        "--output", metavar="COLUMN", help="the measured column, when the model has several outputs"
    )
    extend.add_argument(
        "--verify",
        type=Path,
        metavar="OTHER.csv",
        help="also report fit %% before/after on this record (not used for fitting)",
    )
    extend.add_argument(
        "--catalogue",
        type=Path,
        metavar="FILE",
        help="extra effect catalogue (see config/effects.yaml)",
    )
    extend.add_argument(
        "--force",
        action="store_true",
        help="add the sub-model even if it does not raise the fit on held-out cycles by "
        "2 points, or the guard rails flag it",
    )
    extend.add_argument("--json", action="store_true", help="print one JSON object")
    data_options(
        extend,
        scored="fitted and scored (the residue is that of the model run from the file's start)",
    )
    extend.set_defaults(handler=_extend)


def _extend(args: argparse.Namespace) -> int:
    parent = load_model(args.model)
    data = load_data_from_args(args)
    span = span_from_args(args, data, min_samples=MIN_SAMPLES)
    verify_data = load_data_from_args(args, args.verify) if args.verify else None
    effect = load_catalogue(args.catalogue).effect_for(args.effect)
    command = (
        "compd " + shlex.join(["extend", *sys.argv[2:]]) if sys.argv[1:2] == ["extend"] else ""
    )
    with progress_reporter(enabled=not args.json) as progress:
        extension = extend_model(
            parent,
            data,
            signal=args.effect,
            effect=effect,
            column=args.output,
            order=args.order,
            method=args.method,
            command=command,
            progress=progress,
            force=args.force,
            span=span,
        )
    yaml_text = extension.yaml_text
    verified: tuple[float, float] | None = None
    if verify_data is not None:
        verified = verify_extension(extension, verify_data)
        yaml_text = with_verification(extension, verify_data.path, *verified)
    write_model_text(
        args.out, yaml_text, parent=parent.doc.provenance, parent_path=Path(parent.path)
    )

    model_s = parent.model.sample_time_s
    tfs = [sub.tf for sub in extension.submodels if isinstance(sub.tf, DiscreteTF)]
    taus = [[float(t) for t in tf.time_constants_s(model_s)] for tf in tfs]
    described: list[dict[str, object]] = [
        {
            "name": sub.name,
            "order": tf.order,
            "nk": tf.nk,
            "time_constants_s": tau,
            "static_gain_um_per_unit": float(tf.static_gain()),
        }
        for sub, tf, tau in zip(extension.submodels, tfs, taus, strict=True)
    ]
    first = described[0]
    static_gain = float(sum(tf.static_gain() for tf in tfs))  # the signal's, all lags together
    time_constants = sorted({t for tau in taus for t in tau}, reverse=True)
    summary: dict[str, object] = {
        "model": str(args.model),
        "model_sha256": parent.sha256,
        "out": str(args.out),
        "output": extension.output,
        "effect_signal": args.effect,
        "effect": effect,
        "submodel": first["name"],
        "submodels": described,
        "method": extension.identification.method,
        "order": first["order"],
        "nk": first["nk"],
        "time_constants_s": time_constants,
        "static_gain_um_per_unit": static_gain,
        "residue_fit_percent": json_clean(extension.residue_fit),
        "fit_percent_before": json_clean(extension.fit_before),
        "fit_percent_after": json_clean(extension.fit_after),
        "held_out": {
            "folds": extension.held_out.folds,
            "fit_percent_before": json_clean(extension.held_out.before),
            "fit_percent_after": json_clean(extension.held_out.after),
        },
        "findings": [f.describe() for f in extension.findings],
        "verify": None
        if verified is None
        else {
            "data": str(args.verify),
            "fit_percent_before": json_clean(verified[0]),
            "fit_percent_after": json_clean(verified[1]),
        },
        **span.json(),
    }
    if args.json:
        print(json_text(summary))
        return 0
    out = console()
    names = ", ".join(str(d["name"]) for d in described)
    out.print(
        Text.assemble("added ", (names, "bold"), f" to {extension.output}: {effect} ")
        + f"(input {args.effect} as a change from start; {extension.identification.method}, "
        f"order {first['order']}, nk {first['nk']}, time constants "
        f"{', '.join(f'{t:.0f}' for t in time_constants) or '-'} s, "
        f"static gain {static_gain:.4g} um/unit)"
    )
    out.print(
        f"the new sub-model(s) alone reproduce the residue with {fmt(extension.residue_fit, 1)} % fit"
    )
    table = Table(
        "data", "fit % before", "fit % after", "change (points)", title="free-run simulation fit"
    )
    held = extension.held_out
    rows = [
        (str(args.data), extension.fit_before, extension.fit_after),
        (f"held-out parts of it ({held.folds}; regularised)", held.before, held.after),
    ]
    if verified is not None:
        rows.append((f"{args.verify} (not used for fitting)", *verified))
    for name, before, after in rows:
        table.add_row(name, fmt(before, 1), fmt(after, 1), fmt(after - before, 1))
    out.print(table)
    for finding in extension.findings:
        print(finding.describe(), file=sys.stderr)
    if not span.whole:
        out.print(span.describe("fitted"))
    out.print(f"wrote {args.out}")
    return 0
