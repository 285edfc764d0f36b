"""Adding a missing physical effect to a model by superposition (Horejs 2015 sect. 4.3).

The steps of the paper, for one axis output:

1. run the current model over a record in which the effect is present;
2. take its residue ``Y - Y_hat`` as the response and the effect's signal
   (as a change from its value at start) as the excitation, and identify a
   TF between them;
3. add that TF as a new sub-model: the output becomes the old sum plus the
   new contribution. The existing sub-models are kept exactly as they were.

The new model is written through the model-file writer and read back with the
model-file parser before anything is reported, so the figures quoted are
those of the file a user will load (what it records: :mod:`compd.toolkit.extendrecord`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from compd.errors import DataFileError, ModelError
from compd.files.data import DataSet
from compd.files.equations import kept_periods
from compd.files.experiments import Stacked, as_stacked, single
from compd.files.modelfigures import extension_headline
from compd.files.modelfile import ModelFile, parse_model
from compd.files.modelwriter import model_to_yaml
from compd.model.guards import Finding, Severity
from compd.model.identify import Identification
from compd.model.lagbank import lag_name
from compd.model.metrics import fit_percent
from compd.model.structure import InputSpec, Model, SubModel
from compd.model.transfer import DiscreteTF, resample_discrete
from compd.toolkit.candidates import guard_findings, refuse_errors
from compd.toolkit.derived import consistency_note, kept_priors, kept_residuals
from compd.toolkit.evaluate import Evaluation, compare, evaluate_each, measured_columns
from compd.toolkit.extendjudge import (
    RULE,
    HeldOut,
    Prior,
    judge_signal,
    same_record_extensions,
    without_prior,
)
from compd.toolkit.extendrecord import ExtensionRecord, Tried, extension_yaml
from compd.toolkit.fitchecks import check_input_units
from compd.toolkit.methods import FitMethod, Prepared, method_named, writes_lags
from compd.toolkit.nestedselect import LAG_BANK
from compd.toolkit.span import Span, span_data, until_stop


@dataclass(frozen=True)
class Extension:
    """A model extended by the sub-model(s) of one signal, with the evidence for it."""

    parent: ModelFile
    extended: ModelFile
    yaml_text: str
    output: str
    measured_column: str
    #: The new sub-models: one TF, or with ``method="lagbank"`` one per lag of the signal.
    submodels: tuple[SubModel, ...]
    identification: Identification
    fit_before: float
    fit_after: float
    #: Free-run fit of the new sub-model alone on the residue (Horejs 2015: 86 % on rough cutting).
    residue_fit: float
    #: The model's fit on held-out parts of the record without and with a sub-model on the signal.
    held_out: HeldOut
    #: Guard-rail findings on the new sub-model (warnings; errors refuse it unless forced).
    findings: list[Finding]
    #: Signals of earlier extensions on this record, re-identified together with this one.
    refitted: tuple[str, ...] = ()
    #: The method's first choice failed the guard rails; its fallback was added instead.
    fell_back: bool = False
    #: What the new file could not keep of its parent (a probe prior), for the user.
    notes: tuple[str, ...] = ()


def extend_model(
    parent: ModelFile,
    data: DataSet | Stacked,
    *,
    signal: str,
    effect: str,
    column: str | None = None,
    order: int | str = "auto",
    method: str = "auto",
    command: str = "",
    force: bool = False,
    progress: Callable[[str, float], None] | None = None,
    span: Span | None = None,
    tried: Sequence[Tried] = (),
) -> Extension:
    """Identify a sub-model from ``signal`` to ``parent``'s residue on ``data`` and add it.

    The signal must first earn its place by :data:`~compd.toolkit.extendjudge.RULE`
    (:func:`~compd.toolkit.extendjudge.judge_signal`), and the new sub-model
    must pass the guard rails; otherwise nothing is added unless ``force``.
    Sub-models an earlier extension fitted on this record are re-identified
    together with the new one (:mod:`compd.toolkit.extendjudge`). ``tried``:
    the signals compared before this one was chosen, for the record.
    ``column`` names the measured displacement when the data does not name
    it after the model output (see :func:`compd.toolkit.evaluate.measured_columns`);
    with several outputs it selects the one to extend. ``span``
    (``--from``/``--until``): the models run from the record's start, the new
    sub-model is fitted and every fit % taken on the span's samples only.
    ``method``: ``auto`` is ``oe``, or the lag bank the held-out check fitted
    when the OE sub-model fails the guard rails (a near-integrator that
    another cancels); ``oe``, ``arx`` or ``lagbank`` as named.

    ``data`` may be several experiments (:class:`~compd.files.experiments.Stacked`:
    warm-up runs, days, files that are not one run): the model runs from its
    initial state at each file's start, the sub-model is judged leaving one
    file out at a time and is the regularised lag bank over all of them,
    every lag from rest at each start (OE and ARX identify one record).
    """
    runs = as_stacked(data)
    data, starts = runs.data, runs.starts
    several = len(starts) > 1
    how = method_named(method)
    if several:
        _check_several(data, how, len(starts), span)
        how = method_named(LAG_BANK)  # the regularised lag bank over every file
    first = 0
    if span is not None and not several:
        data, first = until_stop(data, span), span.start
        runs = single(data)
    before = evaluate_each(parent, runs, as_logged=first > 0)
    output, measured_name = _one_output(before, column)
    check_effect_signal(data, signal, measured_name)
    measured = before.data.column(measured_name)  # as judged (compd.toolkit.zeroing)
    prior = same_record_extensions(parent, output, data, signal)
    root = without_prior(before, output, prior)
    residue = measured - root
    held_out, bank = judge_signal(
        data, measured, root, signal, prior=prior, first_sample=first, starts=starts
    )
    if not held_out.accepted and not force:
        raise DataFileError(
            data.path,
            f"{signal!r} does not help enough: a sub-model on it {held_out.describe()}; "
            f"{RULE}. Nothing was written",
            where=f"--effect {signal}",
            fix="Try the next candidate of compd diagnose, or --force to add it anyway",
        )
    signals = (*prior.signals, signal)
    effects = {**prior.effects, signal: effect}
    taken = {
        s.name for o in parent.model.outputs for s in o.submodels if s.name not in prior.submodels
    }

    # The regularised lag bank that earned the signal its place is the lag bank's sub-model.
    prepared = Prepared(
        residue,
        {s: data.column(s) - data.column(s)[0] for s in signals},
        data.sample_time_s,
        order=order,
        first_sample=first,
        progress=progress,
    )

    def submodels_by(by: FitMethod) -> tuple[Identification, tuple[SubModel, ...]]:
        found = by.identify(prepared, bank)
        made = _submodels(found, effects, taken, data, parent, starts)
        # The new signal's sub-models first, then those refitted with it.
        return found, tuple(sorted(made, key=lambda sub: sub.input.signal != signal))

    first_choice, fallback = how.for_extension()
    identification, submodels = submodels_by(first_choice)
    fell_back = False
    if fallback is not None and _guard_errors(data, parent, output, submodels, signal, prior):
        # OE found an implausible sub-model (a near-integrator balanced by another): the
        # regularised lag bank the held-out check fitted is stable by construction.
        identification, submodels = submodels_by(fallback)
        fell_back = True
    names = [sub.name for sub in submodels]
    model = _with_submodels(parent.model, output, submodels, signal, drop=prior.submodels)
    record = ExtensionRecord(signal, names, prior.signals, tuple(tried), held_out)
    provisional = extension_yaml(parent, model, data, record, {}, {}, command)
    after = evaluate_each(parse_model(provisional, parent.path), runs)
    fit_before = fit_percent(measured[first:], before.predicted(output)[first:])
    fit_after = fit_percent(measured[first:], after.predicted(output)[first:])
    added = sum(_contribution(after, output, name) for name in names)
    residue_fit = fit_percent(residue[first:], np.asarray(added)[first:])
    yaml_text = extension_yaml(
        parent,
        model,
        # The calibration's ranges widen by the record as judged: a displacement not zeroed at
        # its start (taken as its change from there) would widen the output's to its raw values.
        before.data if first == 0 or span is None else span_data(data, span),
        record,
        {output: fit_before},
        {output: fit_after},
        command,
        calibration_rms_um=_rms((measured - after.predicted(output))[first:]),
        output=output,
    )
    extended = parse_model(yaml_text, parent.path)  # beside the parent, where its sidecars are
    findings = [f for f in guard_findings(data, model) if set(names) & set(f.submodel.split(" + "))]
    if not force:
        refuse_errors(
            data,
            findings,
            what="the new sub-model is implausible for this record",
            where=f"--effect {signal}",
        )
    return Extension(
        parent=parent,
        extended=extended,
        yaml_text=yaml_text,
        output=output,
        measured_column=measured_name,
        submodels=submodels,
        identification=identification,
        fit_before=fit_before,
        fit_after=fit_after,
        residue_fit=residue_fit,
        held_out=held_out,
        findings=findings,
        refitted=prior.signals,
        fell_back=fell_back,
        notes=tuple(
            filter(
                None,
                [
                    # What the judging did to the record (a displacement not zeroed), as fit says it.
                    *(f"{data.path}: {n}" for n in before.data.notes if n not in data.notes),
                    *kept_priors(parent, model)[1],
                    consistency_note(parent, signal),
                ],
            )
        ),
    )


def _submodels(
    found: Identification,
    effects: dict[str, str],
    taken: set[str],
    data: DataSet,
    parent: ModelFile,
    starts: Sequence[int],
) -> tuple[SubModel, ...]:
    """The identified channels as sub-models named ``SIGNAL_effect`` (a lag bank's: per lag).

    Each input's reference, its thermal zero, is its first value: over several
    experiments the mean of their first values (as ``compd fit`` sets them).
    """
    bank = writes_lags(found.method)
    names = set(taken)
    out = []
    for c in found.channels:
        tau = c.time_constant_s or 0.0
        name = _unique(
            lag_name(f"{c.input_name}_effect", tau) if bank else f"{c.input_name}_effect", names
        )
        names.add(name)
        effect = effects[c.input_name]
        out.append(
            SubModel(
                name=name,
                effect=f"{effect} (lag {tau:g} s, lagbank)" if bank else effect,
                # Fitted as changes from the record's first value: that is the input's thermal zero.
                input=InputSpec(
                    c.input_name, reference=float(np.mean(data.column(c.input_name)[list(starts)]))
                ),
                tf=_at_model_rate(c.tf, data, parent),
            )
        )
    return tuple(out)


def _check_several(data: DataSet, how: FitMethod, experiments: int, span: Span | None) -> None:
    """Refuse what works on one record only when ``data`` stacks several experiments."""
    if how.extends_one_record:
        method = how.name
        raise DataFileError(
            data.path,
            f"--method {method} identifies a sub-model on one record, and the data make "
            f"{experiments} experiments (files or runs each run from their own start)",
            where=f"--method {method}",
            fix="Leave --method at auto (the regularised lag bank over every file), or extend "
            "on one file",
        )
    if span is not None and not span.whole:
        raise DataFileError(
            data.path,
            f"--from/--until select part of one record, and the data make {experiments} experiments",
            where="--from/--until",
            fix="Give the files to extend on, or one file with --from/--until",
        )


def _guard_errors(
    data: DataSet,
    parent: ModelFile,
    output: str,
    submodels: tuple[SubModel, ...],
    signal: str,
    prior: Prior,
) -> bool:
    model = _with_submodels(parent.model, output, submodels, signal, drop=prior.submodels)
    names = {s.name for s in submodels}
    return any(
        f.severity is Severity.ERROR and names & set(f.submodel.split(" + "))
        for f in guard_findings(data, model)
    )


def check_effect_signal(data: DataSet, signal: str, measured_name: str) -> None:
    """Refuse an effect that is not a varying signal column of ``data`` (a :class:`DataFileError`)."""
    if signal == measured_name or signal not in data.columns:
        raise DataFileError(
            data.path,
            f"--effect {signal!r} is not a signal column of the file"
            + (" (it is the measured output)" if signal == measured_name else ""),
            fix=f"Use one of: {', '.join(c for c in data.columns if c != measured_name)}",
        )
    if np.ptp(data.column(signal)) == 0.0:
        raise DataFileError(
            data.path,
            f"column {signal!r} is constant, so it cannot explain anything in this record",
            fix="Extend on a record in which the effect varies",
        )
    check_input_units(data, [signal])


def one_output(evaluation: Evaluation, column: str | None) -> tuple[str, str]:
    """The output to extend and its measured column (``column`` selects among several)."""
    return _one_output(evaluation, column)


def verify_extension(extension: Extension, data: DataSet | Stacked) -> tuple[float, float]:
    """Fit % of the parent and of the extended model on data not used for fitting.

    Several files (:class:`~compd.files.experiments.Stacked`): each run from
    its own start, the fit pooled over them, as ``compd compare`` pools it.
    """
    runs = as_stacked(data)
    data = runs.data
    column = extension.measured_column if data.has(extension.measured_column) else None
    fits = []
    for model_file in (extension.parent, extension.extended):
        evaluation = evaluate_each(model_file, runs)
        (comparison,) = [
            c for c in compare(evaluation, column) if c.output == extension.output
        ] or compare(evaluation, extension.output)
        fits.append(comparison.fit_percent)
    return fits[0], fits[1]


def with_verification(extension: Extension, verify_path: str, before: float, after: float) -> str:
    """The extended model's YAML with the verification figures recorded in its last extension entry."""
    doc = extension.extended.doc
    last = doc.provenance.extensions[-1].model_copy(
        update={
            "verify_data": verify_path,
            "verify_fit_percent_before": {extension.output: before},
            "verify_fit_percent_after": {extension.output: after},
        }
    )
    extensions = [*doc.provenance.extensions[:-1], last]
    # The verification record was used for nothing: its figure is the model's headline.
    headline = extension_headline(last, len(extensions) - 1, extension.extended.model.name)
    provenance = doc.provenance.model_copy(
        update={"extensions": extensions, "headline": headline or doc.provenance.headline}
    )
    return model_to_yaml(
        extension.extended.model,
        description=doc.description,
        signals=extension.extended.signal_units(),
        provenance=provenance,
        residuals=kept_residuals(extension.extended),
        consistency=doc.consistency,
        probe_prior=doc.probe_prior,
        run_periods_s=kept_periods(doc.difference_equations),
    )


def _one_output(evaluation: Evaluation, column: str | None) -> tuple[str, str]:
    outputs = evaluation.compiled.output_names
    if column is not None and column in outputs and not evaluation.data.has(column):
        raise DataFileError(
            evaluation.data.path,
            f"the file has no column {column!r} with the measured displacement",
            fix="Pass --output COLUMN naming the measured column",
        )
    pairs = measured_columns(evaluation, column)
    if len(pairs) > 1:
        raise DataFileError(
            evaluation.data.path,
            f"the model has several outputs with measurements here ({', '.join(pairs)})",
            fix="Pass --output COLUMN to say which one to extend",
        )
    ((output, measured),) = pairs.items()
    return output, measured


def _at_model_rate(tf: DiscreteTF, data: DataSet, parent: ModelFile) -> DiscreteTF:
    """The new TF at the parent model's sample time, where every discrete TF of a file lives.

    Identified at the data's rate, it is converted exactly (ZOH d2c, c2d); a
    TF without a continuous equivalent is refused rather than misapplied.
    """
    model_s = parent.model.sample_time_s
    if np.isclose(model_s, data.sample_time_s, rtol=1e-9, atol=0.0):
        return tf
    try:
        return resample_discrete(tf, data.sample_time_s, model_s)
    except ModelError as exc:
        raise DataFileError(
            data.path,
            f"the sub-model identified at the data's {data.sample_time_s:g} s cannot be brought "
            f"to the model's {model_s:g} s ({exc.message})",
            fix="Use --method oe, or data at the model's sample time",
        ) from exc


def _with_submodels(
    model: Model,
    output: str,
    submodels: tuple[SubModel, ...],
    signal: str,
    drop: tuple[str, ...] = (),
) -> Model:
    outputs = tuple(
        dataclasses.replace(
            o, submodels=(*(s for s in o.submodels if s.name not in drop), *submodels)
        )
        if o.name == output
        else o
        for o in model.outputs
    )
    # A new name, so reports and logs can tell the extended model from its parent; all else
    # (the ambient zero, a residual forest, a bias) stays: the new sub-model fits what they leave.
    return dataclasses.replace(model, name=f"{model.name}+{signal}", outputs=outputs)


def _unique(name: str, taken: set[str]) -> str:
    candidate, n = name, 2
    while candidate in taken:
        candidate, n = f"{name}_{n}", n + 1
    return candidate


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


def _contribution(evaluation: Evaluation, output: str, name: str) -> np.ndarray:
    compiled = evaluation.compiled
    owners = compiled.output_matrix.argmax(axis=0)
    index = next(
        i
        for i, sub in enumerate(compiled.submodels)
        if sub.name == name and compiled.output_names[owners[i]] == output
    )
    contribution: np.ndarray = evaluation.result.contributions[:, index]
    return contribution
