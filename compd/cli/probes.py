"""``compd compare --probe-every`` / ``--probes``: the model judged with probe updates (issue 35 item 7).

The options are registered on ``compare``'s and ``report``'s parsers
(:func:`probe_options`); the work is imported only when one is given
(:func:`compare_with_probes`, :func:`probe_runs`).
"""

from __future__ import annotations

import argparse
import re
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from compd.files.data import DataSet
    from compd.toolkit.evaluate import Evaluation
    from compd.toolkit.probecompare import ProbeRun

_INTERVAL = re.compile(r"^\s*(\d+(?:\.\d*)?|\.\d+)\s*(h|min|m|s)?\s*$")
_UNIT_S = {"h": 3600.0, "min": 60.0, "m": 60.0, "s": 1.0, None: 1.0}


def interval_s(text: str) -> float:
    """Seconds from ``2h``, ``30min`` (or ``30m``), ``90s`` or plain seconds; above 0."""
    match = _INTERVAL.match(text)
    value = float(match.group(1)) * _UNIT_S[match.group(2)] if match else float("nan")
    if not value > 0.0:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not an interval: give e.g. 2h, 30min, 90s or seconds (above 0)"
        )
    return value


def probe_options(parser: argparse.ArgumentParser) -> None:
    """``compare``'s probe options."""
    group = parser.add_argument_group(
        "probe updates: the model's coefficients and bias updated at probe instants, judged "
        "between them, the open-loop figure beside it"
    )
    source = group.add_mutually_exclusive_group()
    source.add_argument(
        "--probe-every",
        type=interval_s,
        metavar="INTERVAL",
        help="probes drawn from the measured column every INTERVAL (2h, 30min, 7200) from the "
        "judged part's start (the first one INTERVAL after it), plus noise",
    )
    source.add_argument(
        "--probes",
        type=Path,
        metavar="PROBES.csv",
        help="measured probe values: columns time_s (the record's time axis) and the output's name",
    )
    group.add_argument(
        "--probe-noise-um",
        type=float,
        default=0.5,
        metavar="UM",
        help="the probes' noise, um: drawn with --probe-every, and what the update assumes "
        "(default 0.5)",
    )
    group.add_argument(
        "--seed", type=int, default=0, help="seed of the drawn probes' noise (default 0)"
    )


def wants_probes(args: argparse.Namespace) -> bool:
    return (
        getattr(args, "probe_every", None) is not None or getattr(args, "probes", None) is not None
    )


def refuse_several_records(experiments: Sequence[DataSet]) -> None:
    """Probe updates carry over one whole run: one record, or a recorded run's files joined."""
    from compd.errors import DataFileError

    if len(experiments) > 1:
        raise DataFileError(
            experiments[1].path,
            "probe updates are judged over one record (the update carries over the whole run)",
            where="--probe-every/--probes",
            fix="Give one record, or join a recorded run's files into one",
        )


def probe_runs(args: argparse.Namespace, evaluation: Evaluation) -> list[ProbeRun]:
    """Each judged output of ``evaluation`` updated at the probes the options give, in time order."""
    import pandas as pd

    from compd.toolkit.evaluate import measured_columns
    from compd.toolkit.probecompare import Probes, read_probes, run_probes

    runs = []
    for output, measured in measured_columns(evaluation, args.output).items():
        if args.probes is not None:
            frame = pd.read_csv(args.probes)
            probes = read_probes(str(args.probes), output, {c: frame[c] for c in frame.columns})
        else:
            probes = Probes.every(
                evaluation.data.time_s,
                evaluation.data.column(measured),
                args.probe_every,
                noise_um=args.probe_noise_um,
                seed=args.seed,
            )
        runs.append(
            run_probes(evaluation, output, measured, probes, probe_noise_um=args.probe_noise_um)
        )
    return runs


def compare_with_probes(args: argparse.Namespace) -> int:
    """``compare`` with probe updates: each output open loop and with probes, per probe its innovation."""
    from compd.cli.common import load_experiments_from_args, print_notes, span_from_args
    from compd.cli.terminal import console
    from compd.errors import DataFileError
    from compd.files.modelfile import load_model
    from compd.toolkit.span import evaluate_span
    from compd.toolkit.summary import json_text

    experiments = load_experiments_from_args(args)
    refuse_several_records(experiments)
    data = experiments[0]
    if getattr(args, "report", None) or getattr(args, "wide", False):
        raise DataFileError(
            data.path,
            "--report and --wide do not take probe updates: the probe comparison is a table "
            "(or --json) of its own, and compd report draws it",
            where="--report/--wide with --probe-every/--probes",
            fix="Run compd report MODEL DATA --out REPORT.html with the same probe options",
        )
    span = span_from_args(args, data)
    evaluation = evaluate_span(load_model(args.model), data, span, init=args.init)
    runs = probe_runs(args, evaluation)
    notes = [run.prior.note for run in runs if run.prior.note]
    if args.json:
        summary: dict[str, Any] = {"model": evaluation.compiled.name, "outputs": {}, "notes": notes}
        for run in runs:
            summary["outputs"][run.output] = run.as_dict()
        print(json_text(summary))
        return 0
    print_notes(evaluation)
    for note in notes:
        print(f"note: {note}", file=sys.stderr)
    from rich.table import Table

    out = console()
    for run in runs:
        table = Table(
            "", "fit %", "residue RMS (um)", "residue p-p (um)",
            title=f"{run.output}: open loop and with probe updates ({run.probe_count} probes: "
            f"{run.count('accepted')} accepted, {run.count('confirmed')} taken once confirmed, "
            f"{run.count('rejected')} rejected, {run.count('flagged')} flagged on arrival; "
            f"prior: {run.prior.prior.source})",
        )  # fmt: skip
        for label, c in (("open loop", run.open_loop), ("with probes", run.with_probes)):
            table.add_row(
                label,
                f"{c.fit_percent:.1f}",
                f"{c.residue.rms_um:.3f}",
                f"{c.residue.peak_to_peak_um:.3f}",
            )
        out.print(table)
        steps = Table("time", "measured (um)", "innovation before", "after", "result")
        for s in run.steps:
            hours, minutes = divmod(round(s.time_s / 60.0), 60)
            steps.add_row(
                f"{hours}:{minutes:02d}",
                f"{s.measured_um:.2f}",
                f"{s.innovation_before_um:+.2f}",
                f"{s.innovation_after_um:+.2f}",
                s.result + (" (bounded)" if s.bounded else ""),
            )
        out.print(steps)
    if not span.whole:
        out.print(span.describe("judged"))
    return 0
