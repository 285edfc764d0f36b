"""``compd extend``: add the missing effect to a model as a new sub-model, and show the error fall."""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path
from typing import Any

from rich.table import Table

from compd.cli.common import (
    console,
    data_options,
    fmt,
    load_data_from_args,
    order_arg,
)
from compd.cli.progress import progress_reporter
from compd.effects import load_catalogue
from compd.extend import extend_model, verify_extension, with_verification
from compd.modelfile import load_model
from compd.summary import json_clean, json_text


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
        "--method", choices=("oe", "arx"), default="oe", help="identification method (default oe)"
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
    extend.add_argument("--json", action="store_true", help="print one JSON object")
    data_options(extend)
    extend.set_defaults(handler=_extend)


def _extend(args: argparse.Namespace) -> int:
    parent = load_model(args.model)
    data = load_data_from_args(args)
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
        )
    yaml_text = extension.yaml_text
    verified: tuple[float, float] | None = None
    if verify_data is not None:
        verified = verify_extension(extension, verify_data)
        yaml_text = with_verification(extension, verify_data.path, *verified)
    args.out.write_text(yaml_text)

    tf = extension.tf
    summary: dict[str, object] = {
        "model": str(args.model),
        "model_sha256": parent.sha256,
        "out": str(args.out),
        "output": extension.output,
        "effect_signal": args.effect,
        "effect": effect,
        "submodel": extension.submodel.name,
        "method": extension.identification.method,
        "order": tf.order,
        "nk": tf.nk,
        "time_constants_s": [float(t) for t in tf.time_constants_s(parent.model.sample_time_s)],
        "static_gain_um_per_unit": float(tf.static_gain()),
        "residue_fit_percent": json_clean(extension.residue_fit),
        "fit_percent_before": json_clean(extension.fit_before),
        "fit_percent_after": json_clean(extension.fit_after),
        "verify": None
        if verified is None
        else {
            "data": str(args.verify),
            "fit_percent_before": json_clean(verified[0]),
            "fit_percent_after": json_clean(verified[1]),
        },
    }
    if args.json:
        print(json_text(summary))
        return 0
    out = console()
    out.print(
        f"added [bold]{extension.submodel.name}[/bold] to {extension.output}: {effect} "
        f"(input {args.effect} as a change from start; {extension.identification.method}, "
        f"order {tf.order}, nk {tf.nk}, time constants "
        f"{', '.join(f'{t:.0f}' for t in tf.time_constants_s(parent.model.sample_time_s)) or '-'} s, "
        f"static gain {tf.static_gain():.4g} um/unit)"
    )
    out.print(
        f"the new sub-model alone reproduces the residue with {fmt(extension.residue_fit, 1)} % fit"
    )
    table = Table(
        "data", "fit % before", "fit % after", "change (points)", title="free-run simulation fit"
    )
    rows = [(str(args.data), extension.fit_before, extension.fit_after)]
    if verified is not None:
        rows.append((f"{args.verify} (not used for fitting)", *verified))
    for name, before, after in rows:
        table.add_row(name, fmt(before, 1), fmt(after, 1), fmt(after - before, 1))
    out.print(table)
    out.print(f"wrote {args.out}")
    return 0
