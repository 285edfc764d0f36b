"""Adding a missing physical effect to a model by superposition (seed 001 sect. 4.3).

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

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from threadpoolctl import threadpool_limits

from compd.errors import DataFileError, ModelError
from compd.files.data import DataSet
from compd.files.modelfile import ModelFile, parse_model
from compd.files.modelwriter import model_to_yaml
from compd.model.guards import Finding
from compd.model.identify import Identification, identify
from compd.model.lagbank import LagBankFit, fit_lag_bank, lag_name
from compd.model.metrics import fit_percent
from compd.model.structure import InputSpec, Model, Output, SubModel
from compd.model.transfer import DiscreteTF, resample_discrete
from compd.toolkit.candidates import (
    EXTEND_MARGIN_POINTS,
    folds_of,
    guard_findings,
    lag_bank_identification,
    operating_signal,
    refuse_errors,
)
from compd.toolkit.evaluate import Evaluation, compare, evaluate, measured_columns
from compd.toolkit.extendrecord import extension_yaml
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
    #: Free-run fit of the new sub-model alone on the residue (seed 001: 86 % on rough cutting).
    residue_fit: float
    #: The model's fit on held-out parts of the record without and with a sub-model on the signal.
    held_out: HeldOut
    #: Guard-rail findings on the new sub-model (warnings; errors refuse it unless forced).
    findings: list[Finding]


@dataclass(frozen=True)
class HeldOut:
    """Fit % on held-out cycles before and after adding a (regularised) sub-model on the signal."""

    folds: str
    before: float
    after: float

    @property
    def rise_points(self) -> float:
        return self.after - self.before


def extend_model(
    parent: ModelFile,
    data: DataSet,
    *,
    signal: str,
    effect: str,
    column: str | None = None,
    order: int | str = "auto",
    method: str = "oe",
    command: str = "",
    force: bool = False,
    progress: Callable[[str, float], None] | None = None,
    span: Span | None = None,
) -> Extension:
    """Identify a sub-model from ``signal`` to ``parent``'s residue on ``data`` and add it.

    The signal must first earn its place: a regularised sub-model on it must
    raise the fit on held-out cycles of ``data`` by :data:`EXTEND_MARGIN_POINTS`
    (:func:`judge_signal`), and the new sub-model must pass the guard rails;
    otherwise nothing is added unless ``force``.
    ``column`` names the measured displacement when the data does not name
    it after the model output (see :func:`compd.toolkit.evaluate.measured_columns`);
    with several outputs it selects the one to extend. ``span``
    (``--from``/``--until``): the models run from the record's start, the new
    sub-model is fitted and every fit % taken on the span's samples only.
    """
    first = 0
    if span is not None:
        data, first = until_stop(data, span), span.start
    before = evaluate(parent, data)
    output, measured_name = _one_output(before, column)
    if signal == measured_name or signal not in data.columns:
        raise DataFileError(
            data.path,
            f"--effect {signal!r} is not a signal column of the file"
            + (" (it is the measured output)" if signal == measured_name else ""),
            fix=f"Use one of: {', '.join(c for c in data.columns if c != measured_name)}",
        )
    measured = data.column(measured_name)
    residue = measured - before.predicted(output)
    excitation = data.column(signal)
    if np.ptp(excitation) == 0.0:
        raise DataFileError(
            data.path,
            f"column {signal!r} is constant, so it cannot explain anything in this record",
            fix="Extend on a record in which the effect varies",
        )
    held_out, bank = judge_signal(
        data, measured, before.predicted(output), residue, excitation, first
    )
    if held_out.rise_points < EXTEND_MARGIN_POINTS and not force:
        raise DataFileError(
            data.path,
            f"{signal!r} does not help: a sub-model on it raises the fit on held-out parts of this "
            f"record from {held_out.before:.1f} % to {held_out.after:.1f} % "
            f"({held_out.rise_points:+.1f} points; {held_out.folds}), less than the "
            f"{EXTEND_MARGIN_POINTS:g} points an extension must add. Nothing was written",
            where=f"--effect {signal}",
            fix="Try the next candidate of compd diagnose, or --force to add it anyway",
        )
    taken = {s.name for o in parent.model.outputs for s in o.submodels}
    # Fitted as changes from the record's first value: that is the new input's thermal zero.
    zero = InputSpec(signal, reference=float(excitation[0]))
    if method == "lagbank":
        # The regularised lag bank that earned the signal its place is the sub-model itself.
        identification = lag_bank_identification(bank, [signal], data.sample_time_s)
        submodels = tuple(
            SubModel(
                name=_unique(lag_name(f"{signal}_effect", c.time_constant_s or 0.0), taken),
                effect=f"{effect} (lag {c.time_constant_s or 0.0:g} s, lagbank)",
                input=zero,
                tf=_at_model_rate(c.tf, data, parent),
            )
            for c in identification.channels
        )
    else:
        identification = identify(
            residue,
            {signal: excitation - excitation[0]},
            sample_time_s=data.sample_time_s,
            method=method,  # type: ignore[arg-type]
            order=order,  # type: ignore[arg-type]
            progress=progress,
            first_sample=first,
        )
        (channel,) = identification.channels
        submodels = (
            SubModel(
                name=_unique(f"{signal}_effect", taken),
                effect=effect,
                input=zero,
                tf=_at_model_rate(channel.tf, data, parent),
            ),
        )
    names = [sub.name for sub in submodels]
    model = _with_submodels(parent.model, output, submodels)

    provisional = extension_yaml(parent, model, data, signal, names, {}, {}, command)
    after = evaluate(parse_model(provisional, parent.path), data)
    fit_before = fit_percent(measured[first:], before.predicted(output)[first:])
    fit_after = fit_percent(measured[first:], after.predicted(output)[first:])
    added = sum(_contribution(after, output, name) for name in names)
    residue_fit = fit_percent(residue[first:], np.asarray(added)[first:])
    yaml_text = extension_yaml(
        parent,
        model,
        data if span is None else span_data(data, span),
        signal,
        names,
        {output: fit_before},
        {output: fit_after},
        command,
        calibration_rms_um=_rms((measured - after.predicted(output))[first:]),
        output=output,
    )
    extended = parse_model(yaml_text, "<extended model>")
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
    )


def judge_signal(
    data: DataSet,
    measured: np.ndarray,
    predicted: np.ndarray,
    residue: np.ndarray,
    excitation: np.ndarray,
    first_sample: int = 0,
) -> tuple[HeldOut, LagBankFit]:
    """How much a regularised sub-model on ``excitation`` raises the fit on parts of ``data`` it never saw.

    The residue is fitted by a lag bank on the signal (:mod:`compd.model.lagbank`)
    on all but one operating cycle (or block) at a time, and each held-out
    part predicted; the rise is the fit % of the model plus those held-out
    predictions over the model alone. Returns that and the lag bank fitted on
    every (scored) sample, which ``--method lagbank`` adds as the sub-model.
    """
    folds = folds_of(data, operating_signal(data, None, None))
    u = (excitation - excitation[0])[:, None]
    with threadpool_limits(limits=1, user_api="blas"):
        bank = fit_lag_bank(
            residue,
            u,
            sample_time_s=data.sample_time_s,
            folds=folds,
            fitted=np.arange(len(residue)) >= first_sample,
        )
    assert bank.cv_predicted_um is not None
    held = np.isfinite(bank.cv_predicted_um)
    before = fit_percent(measured[held], predicted[held])
    after = fit_percent(measured[held], predicted[held] + bank.cv_predicted_um[held])
    return HeldOut(folds.describe(), float(before), float(after)), bank


def verify_extension(extension: Extension, data: DataSet) -> tuple[float, float]:
    """Fit % of the parent and of the extended model on data not used for fitting."""
    column = extension.measured_column if data.has(extension.measured_column) else None
    fits = []
    for model_file in (extension.parent, extension.extended):
        evaluation = evaluate(model_file, data)
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
    provenance = doc.provenance.model_copy(
        update={"extensions": [*doc.provenance.extensions[:-1], last]}
    )
    return model_to_yaml(
        extension.extended.model,
        description=doc.description,
        signals=extension.extended.signal_units(),
        provenance=provenance,
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


def _with_submodels(model: Model, output: str, submodels: tuple[SubModel, ...]) -> Model:
    outputs = tuple(
        Output(o.name, (*o.submodels, *submodels)) if o.name == output else o for o in model.outputs
    )
    # A new name, so reports and logs can tell the extended model from its parent.
    return Model(f"{model.name}+{submodels[0].input.signal}", model.sample_time_s, outputs)


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
