"""Where a model fails and which effect it misses: the glue between an evaluation and the numeric core.

:func:`find_failing_windows` cuts one output's residue into windows and
judges them against a tolerance taken from the model's calibration record
(``provenance.calibration``: twice the calibration residue RMS of that
output) and the calibration data's signal ranges. :func:`diagnose_evaluation`
ranks the data's other signals by how much of the residue each explains
(:mod:`compd.model.diagnose`) and names the physical effect behind each from
the effect catalogue (:mod:`compd.files.effects`). The CLI (``compare``,
``diagnose``) and the HTML report both call these two functions, so they
always say the same thing.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from fnmatch import fnmatchcase
from types import MappingProxyType
from typing import Any, Literal

import numpy as np

from compd.errors import DataFileError
from compd.files.data import DataSet
from compd.files.effects import EffectCatalogue, load_catalogue
from compd.model.diagnose import MIN_DIAGNOSED_SAMPLES, Diagnosis, diagnose_residue
from compd.model.experiments import spans
from compd.model.windows import FailingWindow, failing_windows, window_count
from compd.toolkit.evaluate import Evaluation
from compd.toolkit.extendjudge import (
    FOLLOW_MARGIN_POINTS,
    FOLLOW_MIN_PERCENT,
    RULE,
    HeldOut,
    Ranking,
    judge_signals,
    rank_judged,
    same_record_extensions,
    without_prior,
)
from compd.toolkit.span import longer_record_fix

#: Operating conditions reported per failing window (column-name globs, case-insensitive),
#: besides every signal the model reads.
CONDITION_PATTERNS = ("spindle_speed*", "spindle_power*", "feed*", "door*", "*coolant*")
#: Default tolerance: this many times the calibration residue RMS of the output.
TOLERANCE_FACTOR = 2.0
DEFAULT_WINDOW_S = 900.0
#: Candidates (best by explained residue) whose extension ``diagnose`` fits and ranks by.
JUDGED_CANDIDATES = 3

ToleranceSource = Literal["given", "calibration", "record"]


@dataclass(frozen=True)
class WindowsResult:
    """Failing windows of one output's residue, and how they were judged."""

    output: str
    measured_column: str
    window_s: float
    tolerance_um: float
    tolerance_source: ToleranceSource
    """``given`` (``--tolerance-um``), ``calibration`` (2x its RMS) or ``record`` (2x this record's RMS)."""
    windows: tuple[FailingWindow, ...]
    window_count: int
    """Windows in the record (the last may be shorter; one of zero length is not counted)."""
    conditions: tuple[str, ...]
    """Condition signals averaged per window (matching :data:`CONDITION_PATTERNS`, then model signals)."""
    calibration_ranges: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    notes: tuple[str, ...] = ()


@dataclass(frozen=True)
class DiagnosisResult:
    """The candidates of one output's residue, with the effect each stands for."""

    output: str
    measured_column: str
    diagnosis: Diagnosis
    effects: Mapping[str, str]
    """Candidate signal -> physical effect, from the catalogue."""
    notes: tuple[str, ...] = ()
    measured_spread_um: float | None = None
    """RMS of the measured output about its mean on the diagnosed part (the fit %'s denominator)."""
    extended: Mapping[str, HeldOut] = field(default_factory=dict)
    """Per judged candidate: the model's held-out fit without and with an extension on it."""
    tied: tuple[str, ...] = ()
    """The first two candidates, when their extensions are within the noise of the folds."""
    follows_percent: tuple[float, float] | None = None
    """For a tie: the share of the second's changes lags of the first reproduce, and the reverse."""

    @property
    def tie_note(self) -> str:
        """What the user can do about two candidates the folds cannot tell apart."""
        if not self.tied:
            return ""
        a, b = self.tied
        note = (
            f"{a} and {b} explain the residue about equally (held-out fit with each "
            f"{self.extended[a].after:.1f} % and {self.extended[b].after:.1f} %, within the "
            f"spread of the {self.extended[a].n_folds} folds)"
        )
        forward, backward = self.follows_percent or (float("nan"), float("nan"))
        if forward >= FOLLOW_MIN_PERCENT and forward - backward >= FOLLOW_MARGIN_POINTS:
            note += (
                f"; {a} first: {b} follows it (lags of {a} reproduce {forward:.0f} % of the "
                f"changes of {b}, the reverse {backward:.0f} %)"
            )
        return note + (
            f": extend with each and compare (compd extend --effect {a},{b}), or add both"
        )

    @property
    def verdict(self) -> str:
        """The diagnosis in one sentence."""
        d = self.diagnosis
        if not d.candidates:
            return "no candidate signals to test"
        if d.residue_white:
            return "residue is white: no missing effect stands out"
        best = d.candidates[0]
        found = d.missing_effect
        if found is None:
            return (
                f"no logged signal explains the residue: the best, {best.signal}, explains "
                f"{best.explained_percent:.0f} % of its RMS on held-out data against "
                f"{max(best.chance_percent, 0.0):.0f} % by chance ({d.min_explained_percent:.0f} "
                "points above chance needed); the missing effect is not among the candidates"
            )
        verdict = (
            f"most likely missing effect: {self.effects[found.signal]} ({found.signal}) explains "
            f"{found.explained_percent:.0f} % of the residue RMS on held-out data "
            f"(chance level {max(found.chance_percent, 0.0):.0f} %)"
        )
        judged = self.extended.get(found.signal)
        if judged is not None:
            verdict += (
                f"; with it the model fits {judged.after:.1f} % on held-out folds "
                f"(now {judged.before:.1f} %)"
            )
        if self.tied and found.signal in self.tied:
            verdict += "; " + self.tie_note

        if judged is not None and not judged.accepted:
            verdict += (
                f"; but it would not survive compd extend: a sub-model on it {judged.describe()}, "
                f"and {RULE}"
            )
        return verdict


def residue_of(evaluation: Evaluation, output: str, measured_column: str) -> np.ndarray:
    """``measured - predicted`` (Horejs 2015 eq. 3), um."""
    residue: np.ndarray = evaluation.data.column(measured_column) - evaluation.predicted(output)
    return residue


def find_failing_windows(
    evaluation: Evaluation,
    output: str,
    measured_column: str,
    *,
    tolerance_um: float | None = None,
    window_s: float = DEFAULT_WINDOW_S,
) -> WindowsResult:
    """Windows of ``window_s`` whose residue RMS exceeds the tolerance.

    The tolerance is ``tolerance_um`` if given, else twice the model's
    calibration residue RMS for ``output``
    (``provenance.calibration.rms_um``). A model without that record gets
    twice this record's own residue RMS (windows that stand out from the
    rest) and a note saying so. Outside-calibration signals are judged
    against ``provenance.calibration.ranges`` when the model has them.
    """
    data = evaluation.data
    residue = residue_of(evaluation, output, measured_column)
    calibration = evaluation.model_file.doc.provenance.calibration
    notes = []
    source: ToleranceSource
    if tolerance_um is not None:
        if not tolerance_um > 0.0:
            raise DataFileError(
                data.path, f"tolerance {tolerance_um} um is not > 0", fix="Give --tolerance-um > 0"
            )
        tolerance, source = float(tolerance_um), "given"
    elif calibration is not None and output in calibration.rms_um:
        tolerance, source = TOLERANCE_FACTOR * calibration.rms_um[output], "calibration"
    else:
        tolerance, source = TOLERANCE_FACTOR * float(np.sqrt(np.mean(residue**2))), "record"
        notes.append(
            f"{output}: the model has no calibration residue RMS (provenance.calibration.rms_um); "
            "failing windows are those above twice this record's residue RMS. "
            "Give --tolerance-um for a fixed limit"
        )
    ranges = dict(calibration.ranges) if calibration is not None else {}
    if not ranges:
        notes.append(
            f"{output}: the model has no calibration ranges (provenance.calibration.ranges); "
            "signals outside the calibration range are not judged"
        )
    names = condition_signals(data, evaluation.compiled.signals, exclude=(measured_column,))
    # Several experiments stacked: each judged in windows from its own start, none straddling two.
    parts = spans(len(data), evaluation.starts)
    windows: list[FailingWindow] = []
    if tolerance > 0.0:  # a perfect model on this record: nothing can fail
        for part in parts:
            windows += failing_windows(
                data.time_s[part],
                residue[part],
                tolerance_um=tolerance,
                window_s=window_s,
                conditions={n: data.column(n)[part] for n in names},
                ranges=ranges,
            )
    return WindowsResult(
        output=output,
        measured_column=measured_column,
        window_s=window_s,
        tolerance_um=tolerance,
        tolerance_source=source,
        windows=tuple(windows),
        window_count=sum(window_count(data.time_s[part], window_s) for part in parts),
        conditions=names,
        calibration_ranges=MappingProxyType(ranges),
        notes=tuple(notes),
    )


def condition_signals(
    data: DataSet, model_signals: Sequence[str], *, exclude: Sequence[str] = ()
) -> tuple[str, ...]:
    """Columns matching :data:`CONDITION_PATTERNS`, then the model's own signals, without ``exclude``."""
    matched = [
        name
        for name in data.columns
        if any(fnmatchcase(name.lower(), p) for p in CONDITION_PATTERNS)
    ]
    ordered = dict.fromkeys([*matched, *(s for s in model_signals if data.has(s))])
    return tuple(n for n in ordered if n not in exclude)


def default_candidates(evaluation: Evaluation, measured_column: str) -> tuple[str, ...]:
    """Every data column that is not an output, a displacement (``*_um``), the time or a model signal."""
    model = evaluation.compiled
    excluded = {*model.output_names, *model.signals, measured_column}
    return tuple(
        name
        for name in evaluation.data.columns
        if name not in excluded and not name.lower().endswith("_um")
    )


def diagnose_evaluation(
    evaluation: Evaluation,
    output: str,
    measured_column: str,
    *,
    candidates: Sequence[str] | None = None,
    catalogue: EffectCatalogue | None = None,
    judged: int = JUDGED_CANDIDATES,
    **options: Any,
) -> DiagnosisResult:
    """Rank candidate signals by the share of ``output``'s residue each explains on held-out data.

    ``candidates`` default to :func:`default_candidates`; each is taken as a
    change from its first value. Constant columns are left out with a note
    (they cannot explain anything). The scored part of a longer run
    (``evaluation.whole``, ``--from``) is diagnosed with its candidates' lags
    filtered from the record's start. ``options`` go to
    :func:`compd.model.diagnose.diagnose_residue` (``folds``, ``max_lag_s``,
    ``min_explained_percent``, ...).

    The first ``judged`` candidates by explained residue, and any signal an
    earlier ``extend`` of the model tried, are then judged as ``extend``
    judges them (:func:`compd.toolkit.extendjudge.judge_signals`: the model's
    fit on held-out folds with a sub-model on each) and ranked first, best
    extended model first; the first two are ``tied`` when their extensions
    are within the noise of the folds.
    """
    names = default_candidates(evaluation, measured_column) if candidates is None else candidates
    source = evaluation.whole or evaluation
    data = source.data
    notes = []
    signals = {}
    for name in names:
        values = data.column(name)  # an absent column is an error listing the file's columns
        if np.ptp(values) == 0.0:
            notes.append(f"{name} is constant in {data.path}: left out of the candidates")
        else:
            signals[name] = values
    catalogue = load_catalogue() if catalogue is None else catalogue
    try:
        diagnosis = diagnose_residue(
            residue_of(source, output, measured_column),
            signals,
            data.sample_time_s,
            first_sample=evaluation.first_sample,
            **options,
        )
    except ValueError as exc:  # too short a record to cross-validate
        raise DataFileError(
            data.path, str(exc), fix=longer_record_fix(MIN_DIAGNOSED_SAMPLES, data.sample_time_s)
        ) from exc
    effects = {name: catalogue.effect_for(name) for name in signals}
    measured = data.column(measured_column)[evaluation.first_sample :]
    extended: dict[str, HeldOut] = {}
    ranking = Ranking(())
    if judged > 0 and not diagnosis.residue_white and diagnosis.candidates:
        absorbed = _absorbed(
            source, output, measured_column, signals, judged, evaluation.first_sample, options
        )
        extended = _judge(source, output, measured_column, diagnosis, judged, absorbed, evaluation)
        ranking = rank_judged(extended, data, evaluation.first_sample)
        by_name = {c.signal: c for c in diagnosis.candidates}
        rest = [c for c in diagnosis.candidates if c.signal not in extended]
        diagnosis = dataclasses.replace(
            diagnosis, candidates=(*(by_name[s] for s in ranking.order), *rest)
        )
    return DiagnosisResult(
        output=output,
        measured_column=measured_column,
        diagnosis=diagnosis,
        effects=MappingProxyType(effects),
        notes=tuple(notes),
        measured_spread_um=float(np.std(measured)),
        extended=MappingProxyType(extended),
        tied=ranking.tied,
        follows_percent=ranking.follows_percent,
    )


def _absorbed(
    source: Evaluation,
    output: str,
    measured_column: str,
    signals: Mapping[str, np.ndarray],
    count: int,
    first_sample: int,
    options: Mapping[str, Any],
) -> list[str]:
    """The first candidates of the residue before the model's extensions on this record.

    A candidate an earlier extension absorbed explains little of the residue
    now, but is still a way to explain the effect: it stays listed, judged
    together with the extension it competes with.
    """
    data = source.data
    prior = same_record_extensions(source.model_file, output, data, "")
    if not prior.signals:
        return []
    residue = data.column(measured_column) - without_prior(source, output, prior)
    before = diagnose_residue(
        residue,
        {n: v for n, v in signals.items() if n not in prior.signals},
        data.sample_time_s,
        first_sample=first_sample,
        **options,
    )
    return [c.signal for c in before.candidates[:count]]


def _judge(
    source: Evaluation,
    output: str,
    measured_column: str,
    diagnosis: Diagnosis,
    count: int,
    absorbed: Sequence[str],
    scored: Evaluation,
) -> dict[str, HeldOut]:
    """Extension judgements: the first ``count`` candidates, the named one, the absorbed ones."""
    names = [c.signal for c in diagnosis.candidates]
    found = diagnosis.missing_effect
    chosen = {*names[:count], *absorbed} | ({found.signal} if found is not None else set())
    return judge_signals(
        source,
        output,
        measured_column,
        [n for n in names if n in chosen],
        first_sample=scored.first_sample,
    )
