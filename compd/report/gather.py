"""Everything a report shows, computed once from full-resolution data.

Rendering (``figures``, ``html``) only formats and draws what is gathered
here, so every number in a report is the number ``compd compare --json``
prints for the same files: the summary *is* ``compare_json`` of the same
evaluation, and the tables are formatted from it.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from compd.errors import DataFileError
from compd.files.data import DataSet
from compd.model.compiled import qualified_names
from compd.model.experiments import spans
from compd.model.lagbank import lag_prefix
from compd.model.metrics import Comparison
from compd.toolkit.analysis import (
    DEFAULT_WINDOW_S,
    DiagnosisResult,
    WindowsResult,
    default_candidates,
    diagnose_evaluation,
    find_failing_windows,
)
from compd.toolkit.evaluate import Evaluation, measured_columns
from compd.toolkit.evaluate import compare as compare_outputs
from compd.toolkit.probecompare import ProbeRun
from compd.toolkit.summary import compare_summary


@dataclass(frozen=True)
class OutputAnalysis:
    """One model output against its measured column, with what the residue says."""

    output: str
    measured_column: str
    comparison: Comparison
    windows: WindowsResult
    #: The candidate ranking, or the reason there is none.
    diagnosis: DiagnosisResult | str
    #: Several files: each file's own figures (its run from its own start), as compare prints them.
    per_file: tuple[tuple[str, Comparison], ...] = ()


@dataclass(frozen=True)
class ModelRun:
    """One model over the report's data file."""

    evaluation: Evaluation
    outputs: Mapping[str, OutputAnalysis]
    #: Exactly what ``compd compare --json`` prints for this model and data.
    summary: dict[str, Any]

    @property
    def name(self) -> str:
        return self.evaluation.compiled.name

    def contributions(self, output: str) -> dict[str, np.ndarray]:
        """Sub-model name -> its contribution to ``output`` in um, per sample."""
        compiled = self.evaluation.compiled
        row = compiled.output_matrix[compiled.output_names.index(output)]
        names = qualified_names(compiled)
        parts: dict[str, np.ndarray] = {}
        for i in np.flatnonzero(row):
            own = names[int(i)].split("/", 1)[1]
            # A lag bank's lags of one input are one effect: one trace, not five.
            prefix = lag_prefix(own)
            name = own if prefix is None else f"{prefix} (lag bank)"
            term = self.evaluation.result.contributions[:, i]
            parts[name] = parts[name] + term if name in parts else term
        result = self.evaluation.result
        for r, (out_i, residual) in enumerate(compiled.residuals):  # a residual forest
            if compiled.output_names[out_i] == output and result.residuals is not None:
                parts[f"residual forest on {residual.signal}"] = result.residuals[:, r]
        return parts


@dataclass(frozen=True)
class ConditionGroup:
    """Operating-condition columns drawn on one axis (one unit)."""

    label: str
    unit: str
    columns: tuple[str, ...]


@dataclass(frozen=True)
class ReportData:
    """A report's content: the primary model, optionally a second one, the conditions."""

    primary: ModelRun
    other: ModelRun | None
    conditions: tuple[ConditionGroup, ...]
    notes: tuple[str, ...] = field(default=())
    #: The primary model with probe updates (``--probe-every``/``--probes``), per output judged.
    probes: tuple[ProbeRun, ...] = field(default=())

    def probe_run(self, output: str) -> ProbeRun | None:
        return next((run for run in self.probes if run.output == output), None)

    @property
    def data(self) -> DataSet:
        return self.primary.evaluation.data

    @property
    def runs(self) -> tuple[ModelRun, ...]:
        return (self.primary,) if self.other is None else (self.primary, self.other)


def gather(
    evaluation: Evaluation,
    *,
    other: Evaluation | None = None,
    column: str | None = None,
    tolerance_um: float | None = None,
    window_s: float = DEFAULT_WINDOW_S,
    probes: Sequence[ProbeRun] = (),
) -> ReportData:
    """Compare, find failing windows and rank candidates for ``evaluation`` (and ``other``).

    ``other`` must run over the same data; it is compared on the outputs the
    primary model is compared on that it also has (its summary holds those).
    ``probes``: ``evaluation``'s outputs with probe updates (:func:`compd.toolkit.probecompare.run_probes`).
    """
    if other is not None and (
        other.data.path != evaluation.data.path or len(other.data) != len(evaluation.data)
    ):
        raise ValueError(
            f"both models must run over one data file, got {evaluation.data.path!r} "
            f"and {other.data.path!r}"
        )
    primary = _run(evaluation, column, tolerance_um, window_s)
    second = None
    notes: list[str] = []
    if other is not None:
        pairs = {
            out: col
            for out, col in measured_columns(evaluation, column).items()
            if out in other.compiled.output_names
        }
        if column is not None and not pairs and len(other.compiled.output_names) == 1:
            pairs = {other.compiled.output_names[0]: column}
        missing = [o for o in primary.outputs if o not in pairs]
        if missing:
            notes.append(f"{other.compiled.name} has no output {missing}: shown for one model only")
        second = _run(other, column, tolerance_um, window_s, pairs=pairs)
    notes += [run.prior.note for run in probes if run.prior.note]
    return ReportData(
        primary, second, condition_groups(evaluation, other), tuple(notes), tuple(probes)
    )


def _run(
    evaluation: Evaluation,
    column: str | None,
    tolerance_um: float | None,
    window_s: float,
    *,
    pairs: Mapping[str, str] | None = None,
) -> ModelRun:
    if pairs is None:
        pairs = measured_columns(evaluation, column)
        comparisons = compare_outputs(evaluation, column)
    else:
        comparisons = [
            Comparison.of(out, evaluation.data.column(col), evaluation.predicted(out))
            for out, col in pairs.items()
        ]
    windows = [
        find_failing_windows(
            evaluation, c.output, pairs[c.output], tolerance_um=tolerance_um, window_s=window_s
        )
        for c in comparisons
    ]
    outputs = {
        c.output: OutputAnalysis(
            c.output,
            pairs[c.output],
            c,
            w,
            _diagnose(evaluation, c.output, pairs[c.output]),
            _per_file(evaluation, c.output, pairs[c.output]),
        )
        for c, w in zip(comparisons, windows, strict=True)
    }
    return ModelRun(evaluation, outputs, compare_summary(evaluation, comparisons, windows))


def _per_file(
    evaluation: Evaluation, output: str, measured: str
) -> tuple[tuple[str, Comparison], ...]:
    if len(evaluation.starts) < 2:
        return ()
    y, predicted = evaluation.data.column(measured), evaluation.predicted(output)
    parts = spans(len(y), evaluation.starts)
    return tuple(
        (name, Comparison.of(output, y[part], predicted[part]))
        for name, part in zip(evaluation.experiments, parts, strict=True)
    )


def _diagnose(evaluation: Evaluation, output: str, measured: str) -> DiagnosisResult | str:
    """The candidate ranking, or why there is none (the report still shows everything else)."""
    if len(evaluation.starts) > 1:
        return (
            f"the data are {len(evaluation.starts)} files, each run from its own start: compd "
            "diagnose MODEL.yaml FILES diagnoses each alone and judges the effects they name "
            "over all of them"
        )
    if not default_candidates(evaluation, measured):
        return "the data file has no signal besides the model's own to test as a candidate"
    try:
        return diagnose_evaluation(evaluation, output, measured)
    except DataFileError as exc:  # a record too short to cross-validate
        return exc.message


# ---------------------------------------------------------------------------
# Operating conditions

#: Unit suffixes of column names (the house naming habit) -> (axis label, unit shown).
_SUFFIXES: tuple[tuple[str, str, str], ...] = (
    ("_rpm", "spindle speed", "rpm"),
    ("_kw", "power", "kW"),
    ("_mm_per_min", "feed", "mm/min"),
    ("_m_per_min", "feed", "m/min"),
    ("_degc", "temperature", "degC"),
    ("_bar", "pressure", "bar"),
    ("_l_per_min", "flow", "l/min"),
    ("_percent", "percent", "%"),
    ("_um", "displacement", "um"),
)
_ORDER = ("rpm", "kW", "mm/min", "m/min", "degC", "0/1")


def column_unit(name: str, declared: Mapping[str, str]) -> tuple[str, str]:
    """(axis label, unit) of a data column: as the model declares it, else from its name's suffix."""
    lowered = name.lower()
    for suffix, label, unit in _SUFFIXES:
        if lowered.endswith(suffix):
            return label, declared.get(name, unit)
    if name in declared:
        return name, declared[name]
    return name, ""


def _constant(values: np.ndarray) -> bool:
    return values.size == 0 or bool(np.ptp(values) == 0.0)


def _family(name: str) -> str:
    """A unit-less column's axis: its name without a trailing number (``T12`` -> ``T*``).

    A real record logged by someone else often names its sensors ``T1`` ..
    ``T16`` or ``temp_3``: one family, one axis. A name without a number keeps
    an axis of its own.
    """
    stem = re.sub(r"[\s_\-.]*\d+$", "", name)
    return f"{stem}*" if stem and stem != name else name


def declared_units(*evaluations: Evaluation | None) -> dict[str, str]:
    """Signal -> unit as the models declare them (``signals.<name>.unit``), later models last."""
    declared: dict[str, str] = {}
    for ev in evaluations:
        if ev is not None and ev.model_file.doc.signals:
            declared.update({k: v.unit for k, v in ev.model_file.doc.signals.items()})
    return declared


def condition_groups(
    evaluation: Evaluation, other: Evaluation | None = None
) -> tuple[ConditionGroup, ...]:
    """The data's non-displacement columns grouped by unit, speeds and powers first.

    Columns with only the values 0 and 1 (door open, coolant on) share one
    on/off axis; a column whose unit is unknown gets an axis of its own.
    """
    declared = declared_units(evaluation, other)
    groups: dict[tuple[str, str], list[str]] = {}
    for name, values in evaluation.data.columns.items():
        label, unit = column_unit(name, declared)
        if unit == "um" or _constant(values):
            continue  # displacements are the outputs; a constant signal would be an empty panel
        if np.isin(values, (0.0, 1.0)).all() and not re.search(r"_(rpm|kw)$", name, re.I):
            label, unit = "on/off", "0/1"
        elif not unit:
            label = _family(name)  # T1 .. T16 on one axis, not sixteen
        groups.setdefault((label, unit), []).append(name)

    def rank(key: tuple[str, str]) -> tuple[int, str]:
        unit = key[1]
        return (_ORDER.index(unit) if unit in _ORDER else len(_ORDER), key[0])

    return tuple(
        ConditionGroup(label, unit, tuple(groups[(label, unit)]))
        for label, unit in sorted(groups, key=rank)
    )
