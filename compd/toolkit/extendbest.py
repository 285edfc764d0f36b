"""Several candidate effects for one extension: judge each the same way and keep the best.

``compd extend --effect A,B`` (or ``--effect auto``: the first
:data:`AUTO_CANDIDATES` candidates of ``compd diagnose`` by explained
residue) judges every signal by :data:`~compd.toolkit.extendjudge.RULE` on
the same folds (:func:`~compd.toolkit.extendjudge.judge_signals`), keeps the
one whose extended model fits the held-out folds best among those the rule
accepts, and records all of them in the extension's provenance.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from compd.errors import DataFileError
from compd.files.data import DataSet
from compd.files.experiments import Stacked, as_stacked, single
from compd.files.modelfile import ModelFile
from compd.model.diagnose import MIN_DIAGNOSED_SAMPLES
from compd.toolkit.analysis import default_candidates, diagnose_evaluation
from compd.toolkit.evaluate import Evaluation, evaluate, evaluate_each
from compd.toolkit.extend import check_effect_signal, one_output
from compd.toolkit.extendjudge import RULE, HeldOut, judge_signals, rank_judged
from compd.toolkit.extendrecord import Tried
from compd.toolkit.span import Span, scored_part, until_stop

#: ``--effect auto`` tries this many of diagnose's candidates.
AUTO_CANDIDATES = 3


@dataclass(frozen=True)
class Choice:
    """The signals judged, best extended model first, and the one kept."""

    judged: dict[str, HeldOut]
    kept: str

    @property
    def tried(self) -> tuple[Tried, ...]:
        return tuple(Tried(s, h) for s, h in self.judged.items())


def effect_signals(
    text: str,
    parent: ModelFile,
    data: DataSet | Stacked,
    *,
    column: str | None,
    span: Span | None,
) -> list[str]:
    """``--effect``'s signals: ``A,B,...`` as given, or ``auto``: diagnose's first candidates.

    Over several experiments, diagnose's candidates in each file diagnosed
    alone, ranked by the median share of the residue they explain.
    """
    if text.strip() != "auto":
        return list(dict.fromkeys(s.strip() for s in text.split(",") if s.strip()))
    if isinstance(data, Stacked):
        if len(data.experiments) > 1:
            return _auto_over_experiments(parent, data, column)
        data = data.data
    later = span is not None and span.start > 0
    whole = evaluate(parent, data if span is None else until_stop(data, span), as_logged=later)
    evaluation = whole if span is None else scored_part(whole, span)
    output, measured = one_output(whole, column)
    if not _any_varying(whole, measured):
        raise DataFileError(
            data.path,
            "--effect auto: the file has no varying signal besides the model's own",
            fix="Name the signal: --effect SIGNAL",
        )
    result = diagnose_evaluation(evaluation, output, measured, judged=0)
    return [c.signal for c in result.diagnosis.candidates[:AUTO_CANDIDATES]]


def _any_varying(evaluation: Evaluation, measured: str) -> bool:
    """Whether a signal besides the model's own varies in the evaluated record: one to diagnose."""
    data = evaluation.data
    return any(np.ptp(data.column(n)) > 0.0 for n in default_candidates(evaluation, measured))


def _auto_over_experiments(parent: ModelFile, record: Stacked, column: str | None) -> list[str]:
    explained: dict[str, list[float]] = {}
    for data in record.experiments:
        if len(data) < MIN_DIAGNOSED_SAMPLES:
            continue
        evaluation = evaluate(parent, data)
        output, measured = one_output(evaluation, column)
        if not _any_varying(evaluation, measured):
            continue
        result = diagnose_evaluation(evaluation, output, measured, judged=0)
        for c in result.diagnosis.candidates:
            explained.setdefault(c.signal, []).append(c.explained_percent)
    if not explained:
        raise DataFileError(
            record.data.path,
            "--effect auto: no file holds a varying signal besides the model's own in at least "
            f"{MIN_DIAGNOSED_SAMPLES} samples",
            fix="Name the signal: --effect SIGNAL",
        )
    ranked = sorted(explained, key=lambda s: -float(np.median(explained[s])))
    return ranked[:AUTO_CANDIDATES]


def choose_effect(
    parent: ModelFile,
    data: DataSet | Stacked,
    signals: Sequence[str],
    *,
    column: str | None = None,
    force: bool = False,
    span: Span | None = None,
) -> Choice:
    """Judge each of ``signals`` as an extension of ``parent`` on ``data``; the best the rule accepts.

    With none accepted, a :class:`DataFileError` lists each one's figures
    (``force``: the best of them is kept anyway).
    """
    record = as_stacked(data)
    data = record.data
    first = 0
    if span is not None and len(record.starts) == 1:
        data, first = until_stop(data, span), span.start
        record = single(data)
    evaluation = evaluate_each(parent, record, as_logged=first > 0)
    output, measured = one_output(evaluation, column)
    for signal in signals:
        check_effect_signal(data, signal, measured)
    judged = judge_signals(evaluation, output, measured, list(signals), first_sample=first)
    order = list(rank_judged(judged, data, first, record.starts).order)
    passing = [s for s in order if judged[s].accepted]
    if not passing and not force:
        figures = "; ".join(f"{s}: a sub-model on it {judged[s].describe()}" for s in order)
        raise DataFileError(
            data.path,
            f"none of {', '.join(order)} helps enough ({figures}); {RULE}. Nothing was written",
            where=f"--effect {','.join(signals)}",
            fix="Try other candidates of compd diagnose, or --force to add the best anyway",
        )
    return Choice({s: judged[s] for s in order}, (passing or order)[0])
