"""``compd extend``: add the missing effect to a model as a new sub-model, and show the error fall."""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path
from typing import Any

from rich.table import Table
from rich.text import Text

from compd.cli.common import (
    data_options,
    experiments_label,
    load_experiments_from_args,
    order_arg,
    refuse_with_several,
    span_from_args,
)
from compd.cli.progress import progress_reporter
from compd.cli.tablefit import fit_table
from compd.cli.terminal import console
from compd.files.effects import load_catalogue
from compd.files.experiments import as_stacked
from compd.files.modelfile import load_model
from compd.files.provenancepaths import write_model_text
from compd.files.sidecar import copy_sidecars, residual_files
from compd.model.identify import MIN_SAMPLES
from compd.model.transfer import DiscreteTF
from compd.toolkit.extend import extend_model, verify_extension, with_verification
from compd.toolkit.extendbest import AUTO_CANDIDATES, Choice, choose_effect, effect_signals
from compd.toolkit.extendjudge import RULE, held_out_json
from compd.toolkit.methods import EXTEND_METHODS
from compd.toolkit.summary import fmt, json_clean, json_text


def register(commands: Any) -> None:
    extend = commands.add_parser(
        "extend",
        help="identify a sub-model from an effect's signal to the residue and add it (Horejs 2015, sect. 4.3)",
    )
    extend.add_argument("model", type=Path, metavar="MODEL.yaml")
    extend.add_argument(
        "data",
        type=Path,
        nargs="+",
        metavar="DATA",
        help="a record with the effect: a file, the files (a folder) of one recorded run, or "
        "several experiments (warm-up runs, days): each run from its own start, judged one "
        "file out at a time",
    )
    extend.add_argument(
        "--effect",
        required=True,
        metavar="SIGNAL",
        help="the excitation: a column of DATA.csv; several (A,B,...) or 'auto' (the first "
        f"{AUTO_CANDIDATES} candidates of compd diagnose): each is judged on held-out folds and "
        "the best the rule accepts is added",
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
        choices=EXTEND_METHODS,
        default="auto",
        help="identification method; auto (default): oe, or the lag bank when the oe sub-model "
        "fails the guard rails; lagbank: first-order lags at fixed time "
        "constants, ridge-regularised, as the held-out check fits them (one sub-model per lag)",
    )
    extend.add_argument(
        "--output", metavar="COLUMN", help="the measured column, when the model has several outputs"
    )
    extend.add_argument(
        "--verify",
        type=Path,
        metavar="OTHER",
        help="also report fit %% before/after on this record, or on these runs pooled (a "
        "folder; not used for fitting)",
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
        help=f"add the sub-model even if the rule refuses it ({RULE.replace('%', '%%')}), or the guard rails flag it",
    )
    extend.add_argument("--json", action="store_true", help="print one JSON object")
    data_options(
        extend,
        scored="fitted and scored (the residue is that of the model run from the file's start)",
        initial_state=False,  # the residue is that of the model from equilibrium at each start
    )
    extend.set_defaults(handler=_extend)


def _extend(args: argparse.Namespace) -> int:
    parent = load_model(args.model)
    experiments = load_experiments_from_args(args)
    refuse_with_several(
        experiments, {"--from": args.from_s is not None, "--until": args.until_s is not None}
    )
    record = as_stacked(experiments)
    data = record.data
    span = span_from_args(args, data, min_samples=MIN_SAMPLES)
    for note in data.notes:  # what was joined, repaired or left out
        print(f"note: {note}", file=sys.stderr)
    verify_data = as_stacked(load_experiments_from_args(args, args.verify)) if args.verify else None
    catalogue = load_catalogue(args.catalogue)
    command = (
        "compd " + shlex.join(["extend", *sys.argv[2:]]) if sys.argv[1:2] == ["extend"] else ""
    )
    signals = effect_signals(args.effect, parent, record, column=args.output, span=span)
    choice = (
        choose_effect(parent, record, signals, column=args.output, force=args.force, span=span)
        if len(signals) > 1 or args.effect.strip() == "auto"
        else None
    )
    signal = signals[0] if choice is None else choice.kept
    effect = catalogue.effect_for(signal)
    with progress_reporter(enabled=not args.json) as progress:
        extension = extend_model(
            parent,
            record,
            signal=signal,
            effect=effect,
            column=args.output,
            order=args.order,
            method=args.method,
            command=command,
            progress=progress,
            force=args.force,
            span=span,
            tried=() if choice is None else choice.tried,
        )
    yaml_text = extension.yaml_text
    verified: tuple[float, float] | None = None
    if verify_data is not None:
        verified = verify_extension(extension, verify_data)
        yaml_text = with_verification(extension, verify_data.data.path, *verified)
    # The parent's residual forests stay in the new model: their sidecars go beside it.
    copy_sidecars(residual_files(parent.doc), parent.path, args.out)
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
    own = [
        (tf, tau)
        for sub, tf, tau in zip(extension.submodels, tfs, taus, strict=True)
        if sub.input.signal == signal
    ]
    static_gain = float(sum(tf.static_gain() for tf, _ in own))  # the signal's, all lags together
    time_constants = sorted({t for _, tau in own for t in tau}, reverse=True)
    summary: dict[str, object] = {
        "model": str(args.model),
        "model_sha256": parent.sha256,
        "out": str(args.out),
        "output": extension.output,
        "effect_signal": signal,
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
        "held_out": held_out_json(extension.held_out),
        "rule": RULE,
        "refitted": list(extension.refitted),
        "tried": [
            {"signal": s, **held_out_json(h)}
            for s, h in (choice.judged.items() if choice else [(signal, extension.held_out)])
        ],
        "findings": [f.describe() for f in extension.findings],
        "notes": list(extension.notes),
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
    if choice is not None:
        out.print(fit_table(_tried_table(choice), out))
    names = ", ".join(str(d["name"]) for d in described)
    out.print(
        Text.assemble("added ", (names, "bold"), f" to {extension.output}: {effect} ")
        + f"(input {signal} as a change from start; {extension.identification.method}, "
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
        (
            experiments_label(experiments)
            + (" (pooled, each run from its start)" if len(experiments) > 1 else ""),
            extension.fit_before,
            extension.fit_after,
        ),
        (f"held-out parts of it ({held.folds}; regularised)", held.before, held.after),
    ]
    if verified is not None:
        rows.append((f"{args.verify} (not used for fitting)", *verified))
    for name, before, after in rows:
        table.add_row(name, fmt(before, 1), fmt(after, 1), fmt(after - before, 1))
    out.print(fit_table(table, out))
    if len(experiments) > 1:
        out.print(
            f"over {len(experiments)} experiments: the regularised lag bank of the held-out check "
            "(every lag from rest at each file's start)"
        )
    elif extension.fell_back:
        out.print(
            "the oe sub-model failed the guard rails: the regularised lag bank of the held-out "
            "check was added instead"
        )
    if extension.refitted:
        out.print(
            f"re-identified together with it: {', '.join(extension.refitted)} (extended on this "
            "record before)"
        )
    out.print(f"kept: a sub-model on {signal} {held.describe()}; {RULE}")
    for finding in extension.findings:
        print(finding.describe(), file=sys.stderr)
    for note in extension.notes:
        print(f"note: {note}", file=sys.stderr)
    if not span.whole:
        out.print(span.describe("fitted"))
    out.print(f"wrote {args.out}")
    return 0


def _tried_table(choice: Choice) -> Table:
    table = Table(
        "signal",
        "held-out fit % with it",
        "error removed %",
        "folds better",
        "rule",
        title="the effects tried (each judged on the same held-out folds)",
    )
    for signal, held in choice.judged.items():
        verdict = "kept" if signal == choice.kept else ("passes" if held.accepted else "refused")
        table.add_row(
            signal,
            f"{held.before:.1f} -> {held.after:.1f}",
            f"{held.error_removed_percent:.0f}",
            f"{held.folds_improved} of {held.n_folds}",
            verdict,
        )
    return table
