"""``compd model check``, ``compd simulate`` and ``compd compare``: a model file over a data file.

``compare`` also says where the model fails: the residue cut into windows
(``--window-s``, default 15 min), those whose RMS exceeds the tolerance
(``--tolerance-um``, default twice the model's calibration residue RMS) with
the operating conditions then and the signals outside the calibration range
(see :mod:`compd.toolkit.analysis`). JSON layout: top-level ``failing_windows`` is
the list over every compared output, time-ordered per output, each entry
``{output, start_s, end_s, rms_um, outside_calibration, conditions}``;
``outputs.<name>.window_tolerance_um`` is the tolerance used and top-level
``window_tolerance_sources.<name>`` says where it came from.
"""

from __future__ import annotations

import argparse
import sys
from fnmatch import fnmatchcase
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from rich.console import Console
from rich.table import Table
from rich.text import Text

from compd.cli.common import (
    comparison_table,
    data_options,
    load_experiments_from_args,
    print_notes,
    refuse_with_several,
    span_from_args,
    window_options,
)
from compd.cli.probes import compare_with_probes, probe_options, wants_probes
from compd.cli.tablefit import fit_table
from compd.cli.terminal import console
from compd.files.data import DataSet
from compd.files.modelfile import load_model
from compd.model.compiled import qualified_names
from compd.model.metrics import Comparison
from compd.toolkit.analysis import (
    CONDITION_PATTERNS,
    WindowsResult,
    find_failing_windows,
)
from compd.toolkit.evaluate import (
    Evaluation,
    compare,
    evaluate,
    measured_columns,
    mid_transient_note,
    pooled_comparisons,
)
from compd.toolkit.span import evaluate_span
from compd.toolkit.summary import compare_summary, fmt, json_text


def register(commands: Any) -> None:
    sim = commands.add_parser(
        "simulate", help="model output and each sub-model's contribution per sample"
    )
    sim.add_argument("model", type=Path, metavar="MODEL.yaml")
    sim.add_argument(
        "data",
        type=Path,
        nargs="+",
        metavar="DATA",
        help="data files or folders; several are separate experiments, the model run from its "
        "initial state at each file's start (an 'experiment' column numbers them)",
    )
    sim.add_argument("--out", type=Path, required=True, metavar="PRED.csv")
    data_options(sim)
    sim.set_defaults(handler=_simulate)

    cmp_ = commands.add_parser(
        "compare", help="model against measurement: fit %%, residue, reduction"
    )
    cmp_.add_argument("model", type=Path, metavar="MODEL.yaml")
    cmp_.add_argument(
        "data",
        type=Path,
        nargs="+",
        metavar="DATA",
        help="data files or folders (their *.csv and *.parquet, sorted by name); a recorded "
        "run's files are one record, others separate experiments, each run from the initial "
        "state and judged alone, then pooled",
    )
    cmp_.add_argument(
        "--json", action="store_true", help="print one JSON object instead of a table"
    )
    cmp_.add_argument(
        "--report",
        type=Path,
        metavar="OUT.html",
        help="also write the HTML report (as compd report does)",
    )
    cmp_.add_argument(
        "--wide",
        action="store_true",
        help="show every condition column of the failing-windows table, however wide "
        "(default: fit the terminal, leaving out all-zero columns first)",
    )
    window_options(cmp_)
    data_options(cmp_, scored="judged (fit %%, RMS, windows; JSON from_s/until_s)")
    probe_options(cmp_)
    cmp_.set_defaults(handler=_compare)


def _simulate(args: argparse.Namespace) -> int:
    experiments = load_experiments_from_args(args)
    model_file = load_model(args.model)
    frames = []
    for number, data in enumerate(experiments):
        evaluation = evaluate(model_file, data, init=args.init)
        columns = {"time_s": evaluation.data.time_s}
        if len(experiments) > 1:
            columns["experiment"] = np.full(len(data), number)
        for i, name in enumerate(evaluation.compiled.output_names):
            columns[name] = evaluation.result.outputs[:, i]
        for i, name in enumerate(qualified_names(evaluation.compiled)):
            columns[name.replace("/", ".")] = evaluation.result.contributions[:, i]
        for r, (out_i, _) in enumerate(evaluation.compiled.residuals):  # the residual forests
            name = f"{evaluation.compiled.output_names[out_i]}.residual"
            columns[name] = evaluation.result.residuals[:, r]  # type: ignore[index]
        frames.append(pd.DataFrame(columns))
        print_notes(evaluation)
        if len(experiments) > 1:
            print(f"experiment {number}: {data.path}", file=sys.stderr)
    frame = pd.concat(frames, ignore_index=True)
    frame.to_csv(args.out, index=False, float_format="%.6f")
    print(f"wrote {len(frame)} samples x {frame.shape[1] - 1} columns to {args.out}")
    return 0


def _compare(args: argparse.Namespace) -> int:
    if wants_probes(args):
        return compare_with_probes(args)
    experiments = load_experiments_from_args(args)
    if len(experiments) > 1:
        return _compare_several(args, experiments)
    data = experiments[0]
    span = span_from_args(args, data)
    evaluation = evaluate_span(load_model(args.model), data, span, init=args.init)
    comparisons = compare(evaluation, args.output)
    windows = [
        find_failing_windows(
            evaluation,
            output,
            measured,
            tolerance_um=args.tolerance_um,
            window_s=args.window_s,
        )
        for output, measured in measured_columns(evaluation, args.output).items()
    ]
    if args.report:
        from compd.report import write_report  # plotly is imported only when a report is asked for

        write_report(
            args.report,
            evaluation,
            column=args.output,
            tolerance_um=args.tolerance_um,
            window_s=args.window_s,
        )
    transient = mid_transient_note(evaluation, args.output) if args.init == "steady" else None
    if args.json:
        summary = compare_summary(evaluation, comparisons, windows)
        summary["notes"] = [*summary["notes"], *([transient] if transient else [])]
        print(json_text(summary))
        return 0
    print_notes(evaluation)
    for note in (*(n for w in windows for n in w.notes), *([transient] if transient else [])):
        print(f"note: {note}", file=sys.stderr)
    out = console()
    out.print(fit_table(comparison_table(evaluation, comparisons), out))
    for result in windows:
        out.print(windows_summary(result))
        if result.windows:
            table = windows_table(result, width=None if args.wide else out.width)
            if args.wide:  # the table's own width, not squeezed into the terminal's
                width = max(out.width, table_width(table))
                wide = Console(file=out.file, emoji=False, markup=False, width=width)
                wide.print(table, crop=False)
            else:
                out.print(fit_table(table, out))
    if not span.whole:
        out.print(span.describe("judged"))
    return 0


def _compare_several(args: argparse.Namespace, experiments: list[DataSet]) -> int:
    """Each file judged alone (the model run from its initial state at the file's start), then pooled."""
    refuse_with_several(
        experiments,
        {
            "--from": args.from_s is not None,
            "--until": args.until_s is not None,
            "--report": args.report,
        },
    )
    model_file = load_model(args.model)
    evaluations = [evaluate(model_file, data, init=args.init) for data in experiments]
    per_file = []
    for evaluation in evaluations:
        comparisons = compare(evaluation, args.output)
        windows = [
            find_failing_windows(
                evaluation, output, measured, tolerance_um=args.tolerance_um, window_s=args.window_s
            )
            for output, measured in measured_columns(evaluation, args.output).items()
        ]
        per_file.append((evaluation, comparisons, windows))
    pooled = pooled_comparisons(evaluations, args.output)
    if args.json:
        summary = {
            "model": evaluations[0].compiled.name,
            "experiments": [
                {"data": e.data.path, "machine_id": e.data.metadata.get("machine_id")}
                | compare_summary(e, c, w)
                for e, c, w in per_file
            ],
            "pooled": {"outputs": {c.output: c.as_dict() for c in pooled}},
        }
        print(json_text(summary))
        return 0
    out = console()
    for evaluation, comparisons, windows in per_file:
        print_notes(evaluation, named=True)
        transient = mid_transient_note(evaluation, args.output) if args.init == "steady" else None
        if transient:
            print(f"note: {evaluation.data.path}: {transient}", file=sys.stderr)
        out.print(fit_table(comparison_table(evaluation, comparisons), out))
        for result in windows:
            out.print(windows_summary(result))
            if result.windows:
                out.print(fit_table(windows_table(result, width=out.width), out))
    out.print(fit_table(pooled_table(evaluations, pooled), out))
    return 0


def pooled_table(evaluations: list[Evaluation], pooled: list[Comparison]) -> Table:
    """Every experiment's figures as one: fit % and residue over all files, each run on its own."""
    samples = sum(len(e.data) for e in evaluations)
    table = Table(
        "output",
        "fit %",
        "residue RMS",
        "residue p-p",
        "uncomp. RMS",
        "RMS reduction",
        title=f"{evaluations[0].compiled.name} pooled over {len(evaluations)} files "
        f"({samples} samples; each file run from the initial state at its start); errors in um",
    )
    for c in pooled:
        table.add_row(
            c.output,
            fmt(c.fit_percent, 1),
            fmt(c.residue.rms_um),
            fmt(c.residue.peak_to_peak_um),
            fmt(c.uncompensated.rms_um),
            f"{fmt(c.rms_reduction_percent, 1)} %",
        )
    return table


_SOURCES = {
    "given": "as given",
    "calibration": "2x the calibration residue RMS",
    "record": "2x this record's residue RMS: no calibration record",
}


def windows_summary(result: WindowsResult) -> Text:
    count = len(result.windows)
    return Text.assemble(
        f"{result.output}: ",
        (f"{count} of {result.window_count} windows", "red" if count else "green"),
        f" of {result.window_s / 60:g} min above {result.tolerance_um:.2f} um RMS "
        f"({_SOURCES[result.tolerance_source]})",
    )


#: The failing-windows table's own columns, never dropped for width.
_OUTSIDE = "outside calibration"


def windows_table(result: WindowsResult, *, width: int | None = None) -> Table:
    """Failing windows: span (h:mm from the start), RMS, mean conditions, outside-calibration signals.

    ``width`` is the terminal's: the span, the RMS and the outside-calibration
    column always fit in it. A table that fits whole is shown whole;
    otherwise condition columns whose mean is zero in every failing window
    (a door never opened, no feed) say nothing and go first, then condition
    columns from the right until the table fits, named in the caption.
    ``None`` (``--wide``) shows every condition column, nothing wrapped:
    print it at :func:`table_width`.
    """
    shown = _shown(result)
    whole = _table(result, shown, width=None)
    if width is None or table_width(whole) <= width:
        return whole
    dropped = [n for n in shown if all(w.conditions[n] == 0.0 for w in result.windows)]
    shown = [n for n in shown if n not in dropped]
    while shown and table_width(_table(result, shown, width=1)) > width:
        dropped.append(shown.pop())
    table = _table(result, shown, width=width)
    if dropped:
        table.caption = (
            f"left out for width: {', '.join(dropped)} (all-zero ones first); --wide shows all"
        )
    return table


def _table(result: WindowsResult, shown: list[str], *, width: int | None) -> Table:
    """The table with the condition columns ``shown``, laid out for ``width`` columns.

    Column widths are set here, not left to rich: squeezing a table into a
    terminal, rich cuts words (``spind…``) rather than wrap them. With a
    ``width``, headers wrap between the words of a column name, each column
    is its longest word wide and the outside-calibration column takes the
    rest (its header on one line). ``None``: each column is its longest cell.
    """
    narrow = width is not None
    heads = [
        "from",
        "to",
        "residue RMS (um)",
        *(name.replace("_", " ") if narrow else f"mean {name}" for name in shown),
        _OUTSIDE,
    ]
    rows = [
        [
            _clock(w.start_s),
            _clock(w.end_s),
            f"{w.rms_um:.2f}",
            *(f"{w.conditions[n]:.4g}" for n in shown),
            ", ".join(w.outside_calibration) or "-",
        ]
        for w in result.windows
    ]
    widths = []
    for k, head in enumerate(heads):
        cells = [head, *(row[k] for row in rows)]
        widths.append(
            max(len(word) for cell in cells for word in cell.split())
            if narrow
            else max(len(cell) for cell in cells)
        )
    if width is not None:
        used = sum(widths[:-1]) + 3 * len(widths) + 1  # 2 padding + 1 border per column
        whole = max(len(row[-1]) for row in rows)  # the longest list on one line, no wider
        widths[-1] = max(widths[-1], len(_OUTSIDE), min(width - used, whole))
    table = Table(title="mean over each window" if narrow and shown else None)
    for k, (head, least) in enumerate(zip(heads, widths, strict=True)):
        table.add_column(
            head,
            width=least,
            justify="right" if 2 < k < len(heads) - 1 else "left",
            no_wrap=not narrow,
        )
    for w, row in zip(result.windows, rows, strict=True):
        outside = set(w.outside_calibration)
        marked = [
            Text(c, style="bold red") if n in outside else c
            for n, c in zip(shown, row[3:-1], strict=True)
        ]
        last = Text(row[-1], style="bold red") if outside else row[-1]
        table.add_row(*row[:3], *marked, last)
    return table


def table_width(table: Table) -> int:
    """Terminal columns ``table`` (of :func:`windows_table`) takes: what ``--wide`` prints it at."""
    return sum((c.width or 0) + 3 for c in table.columns) + 1


def _shown(result: WindowsResult) -> list[str]:
    """The operating-condition columns (spindle, feed, door, coolant) shown in the table."""
    return [
        n for n in result.conditions if any(fnmatchcase(n.lower(), p) for p in CONDITION_PATTERNS)
    ]


def _clock(seconds: float) -> str:
    minutes = round(seconds / 60.0)
    return f"{minutes // 60}:{minutes % 60:02d}"
