"""``compd model check`` and ``compd model load``: one model file, checked or put into service.

``compd model updates`` and ``export --updated`` (what the probes taught) are in
:mod:`compd.cli.modelupdates`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from compd.cli.args import broker_option, daemon_options
from compd.cli.modelprobe import register as register_probe
from compd.cli.modelupdates import register as register_updates


def register(commands: Any) -> None:
    model = commands.add_parser(
        "model", help="model files: check one, load one into the running daemon, roll one out"
    ).add_subparsers(metavar="ACTION")
    check = model.add_parser("check", help="validate and compile a model file; show its sub-models")
    check.add_argument("model", type=Path, metavar="MODEL.yaml", help="a path, or bundled:NAME")
    check.add_argument(
        "--sample-time-s", type=float, help="compile for this sample time (default: the model's)"
    )
    check.set_defaults(handler=_check)
    precompile = model.add_parser(
        "compile",
        help="write a model file's difference equations at loop periods (what compd run steps)",
        description="Derive each sub-model's difference equation at each --period-s (zero-order "
        "hold; a discrete TF resampled exactly) and write them into the file's "
        "difference_equations section, the rest of the file as it is. compd run steps these "
        "with numpy alone and refuses a file that would need converting. The periods the file "
        "already carries are derived anew and kept. The file's sha256 changes.",
    )
    precompile.add_argument(
        "model", type=Path, metavar="MODEL.yaml", help="a path, or bundled:NAME"
    )
    precompile.add_argument(
        "--period-s",
        type=float,
        action="append",
        metavar="S",
        help="a loop period (a config's period_s) to precompile for; repeat for several "
        "(default 1)",
    )
    precompile.add_argument(
        "--out", type=Path, metavar="FILE.yaml", help="write a copy here (default: rewrite MODEL)"
    )
    precompile.set_defaults(handler=_compile)
    load = model.add_parser(
        "load", help="validate, install and switch the running daemon to a model file"
    )
    load.add_argument(
        "model", type=Path, metavar="MODEL.yaml", nargs="?", help="a path, or bundled:NAME"
    )
    load.add_argument(
        "--previous",
        action="store_true",
        help="load the model that ran before the last 'compd model load' (the way back)",
    )
    daemon_options(load)
    load.set_defaults(handler=_load)
    listing = model.add_parser(
        "list",
        help="the config's model and those 'compd model load' installed: which runs, which is next",
    )
    daemon_options(listing)
    listing.set_defaults(handler=_list)
    add_rollout(model)
    add_rollout(commands)  # also `compd rollout`, beside `compd fleet`
    register_updates(model)
    register_probe(model)


#: ``compd rollout`` and ``compd model rollout``: one command under two names.
ROLLOUT_HELP = "check a model file, send it to many machines through the fleet's MQTT broker"


def add_rollout(parsers: Any) -> None:
    """The roll-out's parser, under ``parsers`` (the top level's and ``compd model``'s alike)."""
    rollout = parsers.add_parser(
        "rollout",
        help=ROLLOUT_HELP,
        description="Check MODEL.yaml, then send it to each machine's "
        "<prefix>/<machine_id>/cmd/model_load (machines with telemetry.accept_models: true); "
        "print each machine's answer. A machine the broker reports offline is not waited for: "
        "it is pending, and takes the model when it is back (its retained desired record). "
        "Exit status 1 if any refused, did not answer or is pending.",
    )
    rollout.add_argument("model", type=Path, metavar="MODEL.yaml", nargs="?")
    broker_option(rollout)
    rollout.add_argument(
        "--machines",
        metavar="M1,M2,... | @FILE",
        help="the machine_ids to send it to, or @FILE with one a line; "
        "with --pending: only these (default: every machine with a desired model)",
    )
    rollout.add_argument(
        "--pending",
        action="store_true",
        help="finish earlier roll-outs: send each online machine whose model is not the one "
        "its roll-out left as desired (no MODEL.yaml)",
    )
    rollout.add_argument(
        "--online",
        action="store_true",
        help="also every machine whose retained birth says it is online now",
    )
    rollout.add_argument(
        "--canary",
        type=int,
        metavar="N",
        help="send to the first N machines first; the rest only if all N took it "
        "(and blended it in, with --wait-blend)",
    )
    rollout.add_argument(
        "--json", action="store_true", help="print the outcomes as JSON, not a table"
    )
    rollout.add_argument(
        "--timeout-s", type=float, default=60.0, help="wait this long for the answers (default 60)"
    )
    rollout.add_argument(
        "--wait-blend",
        action="store_true",
        help="also wait until each machine that accepted it has switched to it",
    )
    rollout.add_argument(
        "--no-local-check",
        action="store_true",
        help="send without checking here first (the machines still check it)",
    )
    rollout.set_defaults(handler=_rollout)


def _check(args: argparse.Namespace) -> int:
    from rich.table import Column, Table
    from rich.text import Text

    from compd import __version__
    from compd.cli.tablefit import fit_table
    from compd.cli.terminal import console
    from compd.files.modelfigures import figure_lines, model_figures
    from compd.files.modelfile import load_model
    from compd.files.modelschema import unread_provenance_keys
    from compd.model.compiled import qualified_names

    model_file = load_model(args.model)
    compiled = model_file.compile(args.sample_time_s)
    warnings = model_file.check_plausible()
    periods = _check_equations(model_file)
    out = console()
    out.print(
        Text.assemble(
            (compiled.name, "bold"),
            f"  {model_file.path}  sha256 {model_file.sha256[:12]}  "
            f"sample time {compiled.sample_time_s:g} s  signals: {', '.join(compiled.signals)}",
        )
    )
    for lead, rest in figure_lines(model_figures(model_file.doc)):
        out.print(Text(lead, style="bold") + Text(rest))
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
    out.print(fit_table(table, out))
    for finding in warnings:
        print(finding.describe(), file=sys.stderr)
    unread = unread_provenance_keys(model_file.doc.provenance)
    if unread:
        out.print(
            f"note: provenance keys this compd {__version__} does not read (written by a newer "
            f"compd?), kept as they are: {', '.join(unread)}",
            markup=False,
        )
    consistency = model_file.consistency()
    if consistency is None:
        out.print(
            "note: no consistency model (fitted before compd wrote one): the daemon checks each "
            "input on its own, and a wrong reading within its limits is not caught; refit with "
            "compd fit to add one",
            markup=False,
        )
    else:
        out.print(
            f"plausibility: {', '.join(consistency.checked)} each predicted from the other "
            f"logged signals ({', '.join(consistency.signals)}); held-out residue sigma "
            + ", ".join(f"{s:.3g}" for s in consistency.sigma),
            markup=False,
        )
    from compd.cli.unguarded import no_envelope_note, prior_note, unchecked_note

    if (unchecked := unchecked_note(model_file, compiled)) is not None:
        out.print(f"note: {unchecked}", markup=False)
    for output in compiled.output_names:
        notes = (
            no_envelope_note(model_file, output, "a daemon's clamp"),
            prior_note(model_file, compiled, output),
        )
        for note in filter(None, notes):
            out.print(f"note: {note}", markup=False)
    from compd.cli.verifytable import print_verifiable
    from compd.service.config.verifiable import model_unverifiable

    print_verifiable(
        out,
        model_unverifiable(model_file, compiled),
        model_file.signal_units() or {},
        "no config: the default plausibility settings, every signal the calibration logged read, "
        "each output's default tolerance; compd check-config judges a config's",
    )
    out.print(
        f"compd run steps it at {periods} (its difference equations, numpy alone); "
        f"another loop period: compd model compile {model_file.path} --period-s S",
        markup=False,
    )
    out.print(Text.assemble(("ok", "green"), ": compiles, causal and stable"))
    return 0


def _check_equations(model_file: Any) -> str:
    """The periods ``compd run`` takes the file at, its stored equations checked against its TFs.

    The check derives them anew (scipy): in a daemon-only install, without
    scipy, they are taken as the file's sha256 ties them to its TFs, and said so.
    """
    import importlib.util

    from compd.errors import ModelError, ModelFileError
    from compd.model.precompiled import check_derived

    periods = ", ".join(f"{p:g} s" for p in model_file.runnable_periods_s()) or "no period"
    if model_file.equations and importlib.util.find_spec("scipy") is None:
        return f"{periods} (its equations not derived anew here: that needs compd[toolkit])"
    for stored in model_file.equations:
        try:
            check_derived(model_file.model, stored)
        except ModelError as exc:
            raise ModelFileError(
                model_file.path,
                exc.message,
                where=exc.where,
                fix=f"Write them anew with 'compd model compile {model_file.path}'",
            ) from exc
    return periods


def _compile(args: argparse.Namespace) -> int:
    from compd.toolkit.precompile import compile_file

    done = compile_file(args.model, args.period_s or [1.0], args.out)
    shown = ", ".join(f"{p:g} s" for p in done.periods_s)
    print(f"{done.path}: " + (f"difference equations at {shown}" if shown else "needs none"))
    if done.stale_s:
        print(
            f"  the equations it carried at {', '.join(f'{p:g} s' for p in done.stale_s)} were "
            "derived from other TFs (a tf changed after they were written): derived anew"
        )
    if done.as_is_s:
        print(
            f"  at {', '.join(f'{p:g} s' for p in done.as_is_s)} its discrete TFs run as they are"
        )
    if done.sha256_after != done.sha256_before:
        print(f"  sha256 {done.sha256_before[:12]} -> {done.sha256_after[:12]}")
    return 0


def _rollout(args: argparse.Namespace) -> int:
    from compd.cli.rolloutcommand import rollout_command

    return rollout_command(args)


def _list(args: argparse.Namespace) -> int:
    from compd.cli.modellist import list_command

    return list_command(args)


def _load(args: argparse.Namespace) -> int:
    from compd.cli.daemon import model_load_command

    return model_load_command(args)
