"""What the command modules share: data and span options, console, formatting, compare output."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import Any

from rich.table import Table

from compd.cli.args import positive_float
from compd.errors import DataFileError
from compd.files.data import DataSet, load_data
from compd.files.yamlplace import BUNDLED, resolve_path
from compd.model.metrics import Comparison
from compd.toolkit.analysis import DEFAULT_WINDOW_S
from compd.toolkit.evaluate import Evaluation
from compd.toolkit.span import Span, parse_time_s, resolve_span
from compd.toolkit.summary import fmt


def data_options(
    parser: argparse.ArgumentParser,
    *,
    initial_state: bool = True,
    scored: str | None = None,
    detail: str = "",
) -> None:
    """``--max-gap-s`` and ``--resample`` (and ``--init``), for every command that reads a data file.

    With ``scored`` (what the command does with the samples: "judged",
    "fitted") also ``--from`` and ``--until`` (:func:`span_options`).
    """
    if initial_state:
        parser.add_argument(
            "--init",
            choices=("steady", "rest", "estimate"),
            default="steady",
            help="initial model state: in equilibrium with the first sample (default), all zero, or "
            "estimated from the measured output over the first hour (for a record that starts "
            "mid-transient, e.g. split off a longer log; judge after that hour with --from)",
        )
    parser.add_argument(
        "--max-gap-s",
        type=float,
        default=60.0,
        help="longest run of missing samples to interpolate, in s (default 60)",
    )
    parser.add_argument(
        "--resample",
        action="store_true",
        help="interpolate irregularly sampled data onto a uniform grid instead of refusing it",
    )
    experiments_option(parser)
    if scored is not None:
        span_options(parser, scored=scored, detail=detail)


def experiments_option(parser: argparse.ArgumentParser) -> None:
    """``--experiments``: how several files (a folder of a recorder's files) become records."""
    parser.add_argument(
        "--experiments",
        choices=("per-run", "per-file", "contiguous"),
        default="per-run",
        help="how several data files become experiments: per-run (default) joins the files "
        "of one recorded run (the recorder marks each file with its run, the file before it "
        "and the gap; a restart, a gap over --max-gap-s, another machine split it), and every "
        "other file is its own; per-file: every file its own, started from rest; contiguous: "
        "also join files without run marks whose timestamps continue the file before "
        "(same machine_id, the missing samples between them within --max-gap-s)",
    )


def span_options(parser: argparse.ArgumentParser, *, scored: str, detail: str = "") -> None:
    """``--from`` and ``--until``: the part of one continuous record that is ``scored``.

    The model still runs from the file's start, with every input's reference
    (its first value) and the model state of the whole record
    (:mod:`compd.toolkit.span`); ``detail`` adds what the command does with it.
    """
    what = (
        f"only samples from TIME on are {scored}; the model still runs from the file's "
        "start (inputs as changes from the file's first values, measured displacement as "
        "logged), so this is not the same as splitting the file"
    )
    parser.add_argument(
        "--from",
        dest="from_s",
        type=time_arg,
        metavar="TIME",
        help=f"{what}. TIME: seconds from the record's first sample or h:m[:s] (e.g. 32:06)"
        + (f". {detail}" if detail else ""),
    )
    parser.add_argument(
        "--until",
        dest="until_s",
        type=time_arg,
        metavar="TIME",
        help=f"only samples before TIME are {scored} (nothing later is read); same TIME forms",
    )


def time_arg(text: str) -> float:
    """An argparse ``type``: :func:`compd.toolkit.span.parse_time_s`."""
    try:
        return parse_time_s(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def span_from_args(args: argparse.Namespace, data: DataSet, *, min_samples: int = 2) -> Span:
    """The samples ``--from``/``--until`` (of :func:`span_options`) select in ``data``."""
    return resolve_span(data, args.from_s, args.until_s, min_samples=min_samples)


def window_options(parser: argparse.ArgumentParser) -> None:
    """``--output``, ``--window-s`` and ``--tolerance-um``: which output, and how failing windows are judged."""
    parser.add_argument(
        "--output",
        metavar="COLUMN",
        help="measured column to compare (default: columns named like the model's outputs)",
    )
    parser.add_argument(
        "--window-s",
        type=positive_float,
        default=DEFAULT_WINDOW_S,
        help=f"length of the windows the residue is judged in, s (default {DEFAULT_WINDOW_S:g})",
    )
    parser.add_argument(
        "--tolerance-um",
        type=positive_float,
        help="residue RMS above which a window fails, um (default: twice the model's "
        "calibration residue RMS; without a calibration record twice this record's)",
    )


def load_data_from_args(
    args: argparse.Namespace, path: str | os.PathLike[str] | list[Path] | None = None
) -> DataSet:
    """One record: ``path`` (default ``args.data``; ``bundled:NAME`` too), or files that are one run.

    A folder or several files are read as :func:`load_experiments_from_args`
    reads them and must make one experiment (the files of one recorded run).
    """
    path = args.data if path is None else path
    paths = path if isinstance(path, list) else [path]
    if len(paths) > 1 or os.path.isdir(paths[0]):
        experiments = _experiments(args, paths)
        if len(experiments) > 1:
            from compd.files.runs import summary

            raise DataFileError(
                ", ".join(map(str, paths)),
                "this command works on one record, and the files make "
                f"{summary(experiments, args.experiments)}",
                fix="Give the files of one recorded run, or one file; --experiments contiguous "
                "joins files whose timestamps continue each other",
            )
        return experiments[0]
    (one,) = paths
    if str(one).startswith(BUNDLED):  # as provenance records a bundled file
        one = resolve_path(str(one), Path("."))
    return load_data(one, max_gap_s=args.max_gap_s, resample=args.resample)


def load_experiments_from_args(
    args: argparse.Namespace, path: str | os.PathLike[str] | list[Path] | None = None
) -> list[DataSet]:
    """``path`` (default ``args.data``), files and folders, as experiments (:mod:`compd.files.experiments`).

    One file is one experiment, read as ``load_data`` reads it; folders and
    several files are checked to be alike, and the files of one recorded run
    joined (``--experiments``).
    """
    path = args.data if path is None else path
    paths = path if isinstance(path, list) else [path]
    if len(paths) == 1 and not os.path.isdir(paths[0]):
        return [load_data_from_args(args, paths[0])]
    return _experiments(args, paths)


def _experiments(args: argparse.Namespace, paths: list[Any]) -> list[DataSet]:
    from compd.files.experiments import load_experiments

    return load_experiments(
        paths,
        max_gap_s=args.max_gap_s,
        resample=args.resample,
        joining=getattr(args, "experiments", "per-run"),
    )


def refuse_with_several(experiments: list[DataSet], options: dict[str, object]) -> None:
    """Refuse the options (name -> value given) that work on one record when there are several."""
    if len(experiments) < 2:
        return
    for option, value in options.items():
        if value:
            raise DataFileError(
                ", ".join(d.path for d in experiments),
                f"{option} works on one record, and the data make {len(experiments)} experiments "
                "(separate files or runs; a note says which)",
                where=option,
                fix=f"Give one data file (or one recorded run's files) with {option}, or leave "
                f"{option} out",
            )


def experiments_label(experiments: list[DataSet]) -> str:
    """How titles name the data: the file, or ``N files (first .. last)``."""
    if len(experiments) == 1:
        return experiments[0].path
    return f"{len(experiments)} files ({experiments[0].path} .. {experiments[-1].path})"


def print_notes(evaluation: Evaluation, *, named: bool = False) -> None:
    """The data's and the evaluation's notes on stderr; ``named``: each after its file's path."""
    prefix = f"{evaluation.data.path}: " if named else ""
    for note in (*evaluation.data.notes, *evaluation.notes):
        print(f"note: {prefix}{note}", file=sys.stderr)


def comparison_table(evaluation: Evaluation, comparisons: list[Comparison]) -> Table:
    data = evaluation.data
    hours = f"{data.time_s[-1] / 3600:.2f} h"
    if data.time_s[0] > 0.0:  # a later part of a run (--from): its hours in the record
        hours = f"{data.time_s[0] / 3600:.2f} .. {hours}"
    table = Table(
        "output",
        "fit %",
        "residue RMS",
        "residue p-p",
        "max |residue|",
        "uncomp. RMS",
        "uncomp. p-p",
        "RMS reduction",
        "p-p reduction",
        title=f"{evaluation.compiled.name} vs {data.path} ({len(data)} samples, "
        f"{data.sample_time_s:g} s, {hours}); errors in um",
    )
    for c in comparisons:
        table.add_row(
            c.output,
            fmt(c.fit_percent, 1),
            fmt(c.residue.rms_um),
            fmt(c.residue.peak_to_peak_um),
            fmt(c.residue.max_abs_um),
            fmt(c.uncompensated.rms_um),
            fmt(c.uncompensated.peak_to_peak_um),
            f"{fmt(c.rms_reduction_percent, 1)} %",
            f"{fmt(c.peak_to_peak_reduction_percent, 1)} %",
        )
    return table


def order_arg(text: str) -> int | str:
    """``--order``: ``auto`` or a whole number >= 1 (an argparse ``type``)."""
    if text == "auto":
        return text
    try:
        order = int(text)
    except ValueError:
        order = 0
    if order < 1:
        raise argparse.ArgumentTypeError(f"must be 'auto' or a whole number >= 1, got {text!r}")
    return order
