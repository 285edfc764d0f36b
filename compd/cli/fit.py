"""``compd fit``: identify a model from calibration data and write it as a model file."""

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
    refuse_with_several,
    span_from_args,
)
from compd.cli.progress import progress_reporter
from compd.cli.residual_options import add_residual_options, write_fit
from compd.cli.tablefit import fit_table
from compd.cli.terminal import console
from compd.errors import DataFileError
from compd.files.modelschema import median_fold_how
from compd.model.collinear import MIN_ABS_CORRELATION
from compd.model.identify import MIN_SAMPLES
from compd.model.lagbank import DEFAULT_TIME_CONSTANTS_S
from compd.toolkit.fit import FitRequest, FitResult, fit_data
from compd.toolkit.methods import FIT_METHODS, writes_lags
from compd.toolkit.nestedselect import BASELINE
from compd.toolkit.selection import select_columns
from compd.toolkit.summary import fmt


def register(commands: Any) -> None:
    parser = commands.add_parser(
        "fit",
        help="identify TFs (by default a lag bank; ARX, OE or MLR on request) from calibration "
        "data and write a model file",
        description="Identify a model of one output column from input columns, taken as changes "
        "from their first value, and write it as a compd.model/1 file. Every fit % printed is the "
        "free-run simulation fit (Horejs 2015, eq. 2), the figure compd compare reproduces.",
    )
    parser.add_argument(
        "--data",
        type=Path,
        required=True,
        nargs="+",
        metavar="CALIB",
        help="calibration data: a file, or several files and folders (their *.csv and *.parquet, "
        "sorted by name): the files of one recorded run joined into one record, others separate "
        "experiments (--experiments): inputs referenced to each experiment's first values, no "
        "lag across experiments, cross-validation leaving one out",
    )
    parser.add_argument(
        "--output", required=True, metavar="COLUMN", help="measured displacement (um)"
    )
    parser.add_argument(
        "--inputs",
        required=True,
        metavar="A,B,C",
        help="input columns, comma-separated: names, globs ('T*', 'spindle_*') or all (every "
        "column but the output, displacements (disp_*, *_um) and the --position column)",
    )
    parser.add_argument(
        "--phase-gate",
        metavar="SIGNAL",
        help="separate heating and cooling (Post-process 2024, eq. 5): per input a cooling TF, always on, "
        "and a heating-difference TF whose input is switched on while SIGNAL > 0",
    )
    parser.add_argument(
        "--position",
        metavar="SIGNAL",
        help="position-dependent feed-axis error (Pahk 2002: m1(T)*P + m2(T)): per input an "
        "offset TF and a slope TF (um per mm) multiplied by SIGNAL minus the reference; the data "
        "must hold measurements at two or more positions",
    )
    parser.add_argument(
        "--position-reference-mm",
        type=float,
        default=0.0,
        metavar="MM",
        help="position at which the slope term is zero, in mm (default 0)",
    )
    parser.add_argument(
        "--denoise",
        metavar="A,B",
        help="inputs to denoise (Swiss-lathe paper): identified with their first EMD mode removed, then "
        "run through a causal low-pass matched to the EMD result and baked into their TFs (the "
        "service cannot run EMD); the figures of both are kept in the provenance",
    )
    parser.add_argument(
        "--denoise-imfs",
        type=int,
        default=1,
        metavar="N",
        help="how many of the fastest EMD modes --denoise removes (default 1, Swiss-lathe paper; on a "
        "finely sampled sensor the first modes are its white noise, so an AC cycle needs more)",
    )
    parser.add_argument(
        "--order",
        default="auto",
        metavar="auto|N",
        help="model order: auto (default; chosen on held-back data) or N in 1..3",
    )
    parser.add_argument(
        "--method",
        choices=FIT_METHODS,
        default="auto",
        help="auto (default): the lag bank or the static regression, whichever is expected to "
        "fit new data better (nested cross-validation over operating cycles); lagbank: the static "
        "regression plus first-order lags at fixed time constants, the lags shrunk toward the "
        "regression by one weight (two-standard-error rule); oe: a denominator per input, fitted "
        "on the simulation error; arx: least squares with a common denominator; mlr: static "
        "linear regression (the baseline)",
    )
    parser.add_argument(
        "--cycles",
        metavar="SIGNAL",
        help="column whose rising edges start an operating cycle, for leave-one-cycle-out "
        "cross-validation (default: the phase gate, else a spindle speed or power column, else "
        "four contiguous blocks)",
    )
    parser.add_argument(
        "--time-constants-s",
        type=_seconds_list,
        default=DEFAULT_TIME_CONSTANTS_S,
        metavar="T0,T1,..",
        help="the lag bank's time constants in s, comma-separated, 0 for the input itself "
        f"(default {','.join(f'{t:g}' for t in DEFAULT_TIME_CONSTANTS_S)})",
    )
    parser.add_argument(
        "--select-inputs",
        action="store_true",
        help="forward selection: add inputs one at a time, each the one that raises the lag "
        "bank's cross-validated fit most, until the next adds less than 1 point; prints the path "
        "(the expected fit on new data is judged with the selection redone inside each fold)",
    )
    parser.add_argument(
        "--force",
        action="store_true",
        help="write the model even if it holds worse on held-out cycles than the static regression",
    )
    parser.add_argument("--out", type=Path, required=True, metavar="MODEL.yaml")
    parser.add_argument("--name", help="model name (default OUTPUT-METHOD)")
    data_options(
        parser,
        initial_state=False,
        scored="fitted (and the fit %% printed is on them)",
        detail="Every method honours it: mlr regresses only those samples; arx fits their "
        "equation errors (earlier samples serve as lags); oe fits their free-run simulation "
        "error, simulated from the file's start; the held-back third for --order auto is the "
        "last third of them; --residual-model fits its forest on them too. Not with --denoise",
    )
    add_residual_options(parser)
    parser.set_defaults(handler=_fit)


def _seconds_list(text: str) -> tuple[float, ...]:
    try:
        return tuple(float(part) for part in text.split(",") if part.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a comma-separated list of seconds (e.g. 0,300,1200,3600,10800)"
        ) from None


def _order(args: argparse.Namespace) -> int | str:
    text = str(args.order).strip().lower()
    if text == "auto":
        return "auto"
    try:
        return int(text)
    except ValueError:
        raise DataFileError(
            str(args.data[0]),
            f"order {args.order!r} is not a number",
            where="--order",
            fix="Use auto or 1..3",
        ) from None


def _fit(args: argparse.Namespace) -> int:
    order = _order(args)
    experiments = load_experiments_from_args(args)
    refuse_with_several(
        experiments,
        {
            "--from": args.from_s is not None,
            "--until": args.until_s is not None,
            "--residual-model": getattr(args, "residual_model", None),
        },
    )
    data = experiments[0]
    args.data_label = experiments_label(experiments)
    for experiment in experiments:
        for note in experiment.notes:
            print(f"note: {note}", file=sys.stderr)
    span = span_from_args(args, data, min_samples=MIN_SAMPLES)
    taken = [args.output, *([args.position] if args.position else [])]
    inputs = select_columns(data, args.inputs, option="--inputs", exclude=taken)
    command = shlex.join(["compd", *sys.argv[1:]]) if sys.argv[1:] else None
    with progress_reporter() as progress:
        request = FitRequest(
            output=args.output,
            inputs=inputs,
            method=args.method,
            order=order,
            cycles=args.cycles,
            time_constants_s=args.time_constants_s,
            select_inputs_first=args.select_inputs,
            force=args.force,
            phase_gate=args.phase_gate,
            position=args.position,
            position_reference_mm=args.position_reference_mm,
            denoise=[n.strip() for n in (args.denoise or "").split(",") if n.strip()],
            denoise_imfs=args.denoise_imfs,
            name=args.name,
            command=command,
            span=span,
        )
        result = fit_data(experiments, request, progress=progress)
    for note in result.notes:
        print(f"note: {note}", file=sys.stderr)
    write_fit(result, data, args, span)
    _report(result, args)
    _report_verifiable(args.out)
    if not span.whole:
        console().print(span.describe("fitted"))
    return 0


def _candidates_table(result: FitResult) -> Table:
    """Each candidate's expected fit on new data (nested) beside its cross-validated and calibration fit."""
    selection = result.selection
    assert selection is not None
    kept = result.identification.method
    table = Table(
        "method",
        "expected on new data %",
        "nested fit %",
        "cross-validated fit %",
        "calibration fit %",
        "",
        title=f"judged by {selection.folds.describe()} (fit on the others, run through the whole "
        "record); nested: every setting chosen inside each training set; expected: the median of "
        "the held-out folds' nested figures (a typical new record)",
    )

    def figure(value: float | None) -> str:
        return "-" if value is None else fmt(value, 1)

    for score in selection.scores:
        note = "kept" if score.method == kept else ""
        if score.method == BASELINE and kept != BASELINE:
            note = "static regression, the baseline"
        table.add_row(
            score.method,
            figure(score.expected_percent),
            figure(score.nested_fit_percent),
            figure(score.cv_fit_percent),
            fmt(score.calibration_fit_percent, 1),
            note,
        )
    if kept not in {s.method for s in selection.scores}:
        table.add_row(
            kept, "not judged", "-", "-", fmt(result.identification.fit_percent, 1), "kept"
        )
    return table


def expectation_line(result: FitResult) -> str | None:
    """The lead line: what the kept model is expected to fit on new data, beside its in-sample fit."""
    selection = result.selection
    score = None if selection is None else selection.score(result.identification.method)
    if score is None or score.expected_percent is None:
        return None
    how = "nested cross-validation" if score.nested_fit_percent is not None else "cross-validation"
    if score.median_fold_percent is not None and score.held_out_percent is not None:
        how += median_fold_how(score.held_out_percent, len(score.fold_fit_percent))
    return (
        f"{score.method} kept: expected fit on new data {fmt(score.expected_percent, 1)} % ({how}); "
        f"{fmt(result.identification.fit_percent, 1)} % on the data it was fitted on"
    )


def _lag_bank_table(result: FitResult, args: argparse.Namespace) -> Table:
    """Per input: its gain at each time constant and in steady state (a row, not five sub-models)."""
    identification = result.identification
    taus = sorted(
        {c.time_constant_s for c in identification.channels if c.time_constant_s is not None}
    )
    table = Table(
        "input",
        *[("gain" if t == 0 else f"lag {t:g} s") for t in taus],
        "static gain (um/unit)",
        "share of output",
        title=f"{result.model.name}: lag bank on {args.data_label} "
        f"({len(identification.simulated_um)} samples, {identification.sample_time_s:g} s); "
        "um per input unit",
    )
    gains: dict[str, dict[float, float]] = {}
    for channel in identification.channels:
        assert channel.time_constant_s is not None
        gains.setdefault(channel.input_name, {})[channel.time_constant_s] = channel.tf.static_gain()
    for name, row in gains.items():
        share = result.input_shares.get(name)
        table.add_row(
            name,
            *[f"{row.get(t, 0.0):.3g}" for t in taus],
            f"{sum(row.values()):.4g}",
            "-" if share is None else f"{share:.0%}",
        )
    return table


def _report_verifiable(path: Path) -> None:
    """What the calibration's other signals cannot verify of each input of the model written."""
    from compd.cli.verifytable import print_verifiable
    from compd.files.modelfile import load_model
    from compd.service.config.verifiable import model_unverifiable

    model_file = load_model(path)
    print_verifiable(
        console(),
        model_unverifiable(model_file, model_file.compile()),
        model_file.signal_units() or {},
        "a fit has no service config: the default plausibility settings, every signal the "
        "calibration logged read, each output's default tolerance; compd check-config judges a config's",
    )


def _report(result: FitResult, args: argparse.Namespace) -> None:
    identification = result.identification
    sample_s = identification.sample_time_s
    if writes_lags(identification.method):
        _report_tail(result, args, _lag_bank_table(result, args))
        return
    table = Table(
        "sub-model",
        "input",
        "gate",
        "nb",
        "order",
        "nk",
        "time constants (s)",
        "static gain (um/unit)",
        title=f"{result.model.name}: {identification.method} on {args.data_label} "
        f"({len(identification.simulated_um)} samples, {sample_s:g} s)",
    )
    for sub, channel in zip(
        result.model.outputs[0].submodels, identification.channels, strict=True
    ):
        tf = channel.tf
        table.add_row(
            sub.name,
            channel.input_name,
            sub.describe_factors(),
            str(len(tf.num)),
            str(tf.order),
            str(tf.nk),
            ", ".join(f"{t:.0f}" for t in tf.time_constants_s(sample_s)) or "-",
            f"{tf.static_gain():.5g}",
        )
    _report_tail(result, args, table)


def _report_tail(result: FitResult, args: argparse.Namespace, table: Table) -> None:
    identification = result.identification
    out = console()
    out.print(fit_table(table, out))
    lead = expectation_line(result)
    if lead is not None:
        out.print(Text(lead, style="bold"))
    residue = result.comparison.residue
    line = (
        f"free-run simulation fit {fmt(identification.fit_percent, 2)} % on the calibration data "
        f"(residue RMS {fmt(residue.rms_um, 3)} um)"
    )
    if identification.validation_fit_percent is not None:
        line += (
            f"; orders chosen on held-back data: fit {fmt(identification.validation_fit_percent, 2)}"
            " % on the last third"
        )
    out.print(line)
    if result.selection is not None:
        out.print(fit_table(_candidates_table(result), out))
    if result.selection_steps:
        path = " -> ".join(
            f"+{s.input} {fmt(s.cv_fit_percent, 1)} %" for s in result.selection_steps
        )
        out.print(
            f"inputs selected by held-out fit ({result.selection.folds.describe() if result.selection else ''}): "
            f"{path}; the next would add < 1 point"
        )
    if result.collinear:
        groups = "; ".join(" ~ ".join(group) for group in result.collinear)
        out.print(
            f"inputs that move together (|r| >= {MIN_ABS_CORRELATION}, one piece of information "
            f"per group): {groups}"
        )
    if len(result.input_shares) > 1 and not writes_lags(identification.method):
        carried = ", ".join(f"{name} {share:.0%}" for name, share in result.input_shares.items())
        out.print(f"share of the model's output carried by each input: {carried}")
    for finding in result.findings:
        print(finding.describe(), file=sys.stderr)
    denoise = result.provenance.denoise
    if denoise is not None:
        for entry in denoise.inputs:
            out.print(
                f"denoised {entry.input}: first {entry.imfs_removed} EMD mode(s) removed for the "
                f"fit; in the file a causal "
                f"low-pass of {entry.lowpass_stages} x {entry.lowpass_tau_s:.0f} s, "
                f"{fmt(entry.lowpass_vs_emd_rms, 4)} {entry.unit} RMS from the EMD result (raw: "
                f"{fmt(entry.raw_vs_emd_rms, 4)} {entry.unit})"
            )
        for name, emd_fit in denoise.fit_percent_emd.items():
            out.print(
                f"{name}: fit {fmt(emd_fit, 2)} % (RMS {fmt(denoise.rms_um_emd[name], 3)} um) on "
                f"the EMD-denoised inputs, {fmt(denoise.fit_percent_lowpass[name], 2)} % (RMS "
                f"{fmt(denoise.rms_um_lowpass[name], 3)} um) as written, on the raw inputs"
            )
    out.print(f"wrote {args.out}")
