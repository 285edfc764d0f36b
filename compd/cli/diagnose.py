"""``compd diagnose``: which physical effect a model is missing, from its residue."""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console
from rich.text import Text

from compd.cli.common import (
    data_options,
    load_experiments_from_args,
    refuse_with_several,
    span_from_args,
)
from compd.cli.diagnosetable import diagnosis_table, table_width
from compd.cli.tablefit import fit_table
from compd.cli.terminal import console, console_at
from compd.files.data import DataSet
from compd.files.effects import EffectCatalogue, load_catalogue
from compd.files.experiments import stack
from compd.files.modelfile import ModelFile, load_model
from compd.model.diagnose import MIN_DIAGNOSED_SAMPLES
from compd.toolkit.analysis import DiagnosisResult, diagnose_evaluation
from compd.toolkit.evaluate import evaluate, evaluate_each, measured_columns
from compd.toolkit.extendbest import AUTO_CANDIDATES
from compd.toolkit.extendjudge import RULE, HeldOut, held_out_json, judge_signals
from compd.toolkit.selection import select_columns
from compd.toolkit.span import evaluate_span
from compd.toolkit.summary import json_clean, json_text

DEFAULT_TOP = 5


def register(commands: Any) -> None:
    diag = commands.add_parser(
        "diagnose",
        help="which logged signal (physical effect) explains the model's residue",
        description="Rank candidate signals by the share of the residue RMS that one or two "
        "first-order lags of each explain on held-out data (blocked cross-validation), against "
        "the share reached by chance (the signal shifted in time), with the residue/input "
        "cross-correlation against its 99 % Bartlett bound as evidence. The first three are "
        "then ranked by the model's fit on held-out folds with the extension each would make "
        "(as compd extend judges it), and two within the noise of the folds are called a tie.",
    )
    diag.add_argument("model", type=Path, metavar="MODEL.yaml")
    diag.add_argument(
        "data",
        type=Path,
        nargs="+",
        metavar="DATA",
        help="data files or folders; a recorded run's files are one record, others separate "
        "experiments, each diagnosed on its own (the model run from its initial state at each "
        "one's start), then summed up",
    )
    diag.add_argument(
        "--output",
        metavar="COLUMN",
        help="measured column to diagnose (default: the first column named like a model output)",
    )
    diag.add_argument(
        "--candidates",
        metavar="A,B,...",
        help="signals to test: names, globs ('T*') or all (every column but the model's outputs, "
        "the measured one and displacements, disp_* and *_um; model inputs included); default: "
        "every column that is not an output, a displacement (*_um), the time or a model input",
    )
    diag.add_argument(
        "--catalogue",
        type=Path,
        metavar="FILE",
        help="extra effect catalogue (YAML, schema compd.effects/1) tried before the bundled one",
    )
    diag.add_argument(
        "--top", type=int, default=DEFAULT_TOP, help=f"candidates shown (default {DEFAULT_TOP})"
    )
    diag.add_argument(
        "--json", action="store_true", help="print one JSON object instead of a table"
    )
    diag.add_argument(
        "--wide",
        action="store_true",
        help="show every column of the table whole, however wide (default: fit the terminal, "
        "leaving out the detail columns, named under the table)",
    )
    data_options(
        diag,
        scored="diagnosed",
        detail="The candidates' lags are filtered from the file's start too",
    )
    diag.set_defaults(handler=_diagnose)


def _diagnose(args: argparse.Namespace) -> int:
    catalogue = load_catalogue(args.catalogue)  # a bad catalogue fails before the long work
    experiments = load_experiments_from_args(args)
    if len(experiments) > 1:
        return _diagnose_several(args, experiments, catalogue)
    data = experiments[0]
    span = span_from_args(args, data, min_samples=MIN_DIAGNOSED_SAMPLES)
    evaluation = evaluate_span(load_model(args.model), data, span, init=args.init)
    output, _, result = _diagnose_one(evaluation, data, args, catalogue)
    if args.json:
        summary = {**diagnosis_json(evaluation.compiled.name, result), **span.json()}
        print(json_text(summary))
        return 0
    for note in (*evaluation.data.notes, *evaluation.notes, *result.notes):
        print(f"note: {note}", file=sys.stderr)
    out = console()
    _print_table(out, args, evaluation.compiled.name, evaluation.data.path, result)
    d = result.diagnosis
    out.print(
        f"residue {output}: RMS {d.residue_rms_um:.2f} um about its mean; autocorrelation "
        f"outside its 99 % Bartlett bounds at {d.whiteness_outside} of {len(d.lags_s) - 1} lags "
        f"(up to {d.whiteness_allowed} by chance): {'white' if d.residue_white else 'not white'}"
    )
    colour = "green" if d.missing_effect is not None else "yellow"
    # Wrapped between words at the terminal's width (a script reads --json's "verdict").
    out.print(Text(result.verdict, style=f"bold {colour}"))
    if not span.whole:
        out.print(span.describe("diagnosed"))
    return 0


def _diagnose_several(
    args: argparse.Namespace, experiments: list[DataSet], catalogue: EffectCatalogue | None
) -> int:
    """Each file diagnosed alone, then which missing effect the files agree on, and the pooled residue."""
    refuse_with_several(
        experiments, {"--from": args.from_s is not None, "--until": args.until_s is not None}
    )
    model_file = load_model(args.model)
    results = []
    for data in experiments:
        evaluation = evaluate(model_file, data, init=args.init)
        output, measured, result = _diagnose_one(evaluation, data, args, catalogue)
        residue = evaluation.data.column(measured) - evaluation.predicted(output)
        results.append((evaluation, result, residue))
    residue = np.concatenate([r for _, _, r in results])
    pooled_rms_um = float(np.sqrt(np.mean((residue - residue.mean()) ** 2)))
    found = Counter(
        r.diagnosis.missing_effect.signal for _, r, _ in results if r.diagnosis.missing_effect
    )
    over_files = _judged_over_files(
        model_file, experiments, [s for s, _ in found.most_common(AUTO_CANDIDATES)], output, args
    )
    name = results[0][0].compiled.name
    if args.json:
        summary = {
            "model": name,
            "experiments": [
                {"data": e.data.path, **diagnosis_json(name, r)} for e, r, _ in results
            ],
            "pooled": {
                "residue_rms_um": pooled_rms_um,
                "missing_effects": dict(found.most_common()),
                "extended_over_files": {s: held_out_json(h) for s, h in over_files.items()},
            },
        }
        print(json_text(summary))
        return 0
    out = console()
    for evaluation, result, _ in results:
        for note in (*evaluation.data.notes, *evaluation.notes, *result.notes):
            print(f"note: {evaluation.data.path}: {note}", file=sys.stderr)
        _print_table(out, args, name, evaluation.data.path, result)
        out.print(result.verdict)
    agreed = ", ".join(f"{signal} in {count}" for signal, count in found.most_common()) or "none"
    out.print(
        f"pooled over {len(results)} files: residue RMS {pooled_rms_um:.2f} um about its mean; "
        f"a missing effect found: {agreed} of {len(results)} files"
    )
    for signal, held in over_files.items():
        verdict = "passes the rule" if held.accepted else "refused by the rule"
        out.print(
            f"over all {len(results)} files, as compd extend on them would judge it: a sub-model "
            f"on {signal} {held.describe()}: {verdict}"
        )
    return 0


def _judged_over_files(
    model_file: ModelFile,
    experiments: list[DataSet],
    signals: list[str],
    output: str,
    args: argparse.Namespace,
) -> dict[str, HeldOut]:
    """The effects the files name, judged over all of them one file out at a time (``extend``'s check).

    As ``extend`` runs the model: from equilibrium at each file's start, whatever ``--init``.
    """
    if not signals:
        return {}
    evaluation = evaluate_each(model_file, stack(experiments))
    measured = measured_columns(evaluation, args.output)[output]
    return judge_signals(evaluation, output, measured, signals)


def diagnosis_json(model_name: str, result: DiagnosisResult) -> dict[str, object]:
    """The ``diagnose --json`` object; ``candidates`` best first, each with ``signal``, ``effect``, ...

    ``candidates[*].signal``, ``.effect`` and ``.explained_percent`` are a contract.
    """
    d = result.diagnosis
    found = d.missing_effect
    return {
        "model": model_name,
        "output": result.output,
        "measured_column": result.measured_column,
        "residue_rms_um": d.residue_rms_um,
        "residue_white": d.residue_white,
        "whiteness_lags": len(d.lags_s) - 1,
        "whiteness_outside": d.whiteness_outside,
        "whiteness_allowed": d.whiteness_allowed,
        "naive_bound": d.naive_bound,
        "missing_effect": None if found is None else found.signal,
        "verdict": result.verdict,
        "rule": RULE,
        "tied": list(result.tied),
        "notes": list(result.notes),
        "candidates": [
            {
                "signal": c.signal,
                "effect": result.effects[c.signal],
                "explained_percent": json_clean(c.explained_percent),
                "chance_percent": json_clean(c.chance_percent),
                "time_constant_s": c.time_constant_s,
                "time_constants_s": list(c.time_constants_s),
                "gain_um_per_unit": c.gain_um_per_unit,
                "gains_um_per_unit": list(c.gains_um_per_unit),
                "sign": c.sign,
                "lag_s": c.lag_s,
                "xcorr_peak": c.xcorr_peak,
                "xcorr_bound": json_clean(c.xcorr_bound),
                "significant": c.significant,
                "extended": None
                if c.signal not in result.extended
                else held_out_json(result.extended[c.signal]),
            }
            for c in d.candidates
        ],
    }


def _print_table(
    out: Console, args: argparse.Namespace, name: str, data_path: str, result: DiagnosisResult
) -> None:
    """The candidate table at the terminal's width, or (``--wide``) at its own."""
    table = diagnosis_table(
        name, data_path, result, args.top, width=None if args.wide else out.width
    )
    if args.wide:  # the table's own width, not squeezed into the terminal's
        out = console_at(out, max(out.width, table_width(table)))
        out.print(table)
    else:
        out.print(fit_table(table, out))


def _diagnose_one(
    evaluation: Any, data: Any, args: argparse.Namespace, catalogue: Any
) -> tuple[str, str, Any]:
    """One record's diagnosis: the output, its measured column and the ranked candidates."""
    output, measured = next(iter(measured_columns(evaluation, args.output).items()))
    candidates = (
        None
        if args.candidates is None
        else select_columns(
            data,
            args.candidates,
            option="--candidates",
            exclude=[*evaluation.compiled.output_names, measured],
        )
    )
    result = diagnose_evaluation(
        evaluation, output, measured, candidates=candidates, catalogue=catalogue
    )
    return output, measured, result
