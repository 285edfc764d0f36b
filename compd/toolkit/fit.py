"""Fitting a model file to a calibration data file: columns in, ``compd.model/1`` model out.

The bridge between files and :func:`compd.model.identify.identify`: takes
the named columns as changes from their first value (the convention
``compd compare`` runs models with, so the fit % printed here is the one
compare reproduces), turns the phase-gate column into a gate, builds the
:class:`~compd.model.structure.Model` and its provenance (the calibration
data's fit, residue RMS and the range of every column, which compare uses to
flag operating conditions the model never saw). With a position column
(Pahk 2002 eq. 5) every input also gets a slope sub-model whose contribution
is multiplied by ``position - reference_mm``. With a :class:`~compd.toolkit.span.Span`
(``--from``/``--until``) only the span's samples are fitted and scored; the
model still runs from the record's first sample (see :mod:`compd.model.identify`).

The option checks are :mod:`compd.toolkit.fitchecks`; the model and provenance
written, :mod:`compd.toolkit.fitmodel`; the candidates compared,
:mod:`compd.toolkit.candidates`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from compd.errors import DataFileError, ModelError
from compd.files.columns import is_recorded_column
from compd.files.data import DataSet
from compd.files.experiments import stack
from compd.files.modelfigures import fit_headline
from compd.files.modelfile import consistency_doc
from compd.files.modelschema import ConsistencyDoc, ProvenanceDoc
from compd.files.modelwriter import model_to_yaml
from compd.files.probeprior import calibration_probe_priors
from compd.model.collinear import collinear_groups
from compd.model.consistency import fit_consistency
from compd.model.experiments import ONE, start_values
from compd.model.guards import Finding
from compd.model.identify import Identification
from compd.model.lagbank import DEFAULT_TIME_CONSTANTS_S
from compd.model.metrics import Comparison
from compd.model.orderfit import Progress
from compd.model.structure import Model, Position
from compd.toolkit.candidates import (
    check_against_regression,
    contributions_of,
    cross_validation_doc,
    folds_of,
    guard_findings,
    input_shares,
    operating_signal,
    refuse_errors,
)
from compd.toolkit.denoise import bake_lowpasses, denoise_columns, denoise_note
from compd.toolkit.fitchecks import check_arguments, check_position
from compd.toolkit.fitmodel import (
    column_unit,
    describe_references,
    fit_provenance,
    identification_to_model,
    with_references,
)
from compd.toolkit.methods import METHODS, Prepared, method_named
from compd.toolkit.nestedselect import Selection, SelectionStep, compare_candidates
from compd.toolkit.selection import is_displacement
from compd.toolkit.span import Span, until_stop
from compd.toolkit.zeroing import zero_displacements


@dataclass(frozen=True, eq=False)
class FitResult:
    """A fitted model, how it was made and how well it simulates its calibration data."""

    identification: Identification
    model: Model
    provenance: ProvenanceDoc
    comparison: Comparison
    yaml_text: str
    #: The candidates' calibration and cross-validated fits, and which was kept.
    selection: Selection | None = None
    #: Guard-rail findings on the written model (warnings; errors refuse it unless forced).
    findings: list[Finding] = field(default_factory=list)
    #: Groups of inputs that move together (one piece of information each).
    collinear: list[tuple[str, ...]] = field(default_factory=list)
    #: Each input's share of the model's contribution RMS, largest first.
    input_shares: dict[str, float] = field(default_factory=dict)
    #: With ``select``: the inputs in the order forward selection added them.
    selection_steps: list[SelectionStep] = field(default_factory=list)
    #: What the fit did to the data that the user should know (a displacement not zeroed).
    notes: tuple[str, ...] = ()


@dataclass(frozen=True)
class FitRequest:
    """What a fit is asked: the columns, the method by name (:data:`~compd.toolkit.methods.METHODS`) and its options.

    ``position``: an axis-position column (mm); every input then also gets a
    slope sub-model multiplied by ``position - position_reference_mm``.
    ``denoise``: inputs identified with their first EMD mode removed and run
    through a matched causal low-pass baked into their TFs (:mod:`compd.toolkit.denoise`);
    ``denoise_imfs`` modes are removed (Swiss-lathe paper: 1). ``span``: fit only its
    samples, the model run from the record's start (nothing after it is read).
    ``cycles``: the column whose rising edges start the held-out operating cycles.
    ``select_inputs_first``: forward selection of the inputs (for the lag bank).
    ``force``: write a model the guard rails or the regression check refuse.
    ``name`` and ``command``: the model's name and the command line, for the file.
    """

    output: str
    inputs: Sequence[str]
    method: str = "auto"
    order: int | str = "auto"
    cycles: str | None = None
    force: bool = False
    time_constants_s: Sequence[float] = DEFAULT_TIME_CONSTANTS_S
    select_inputs_first: bool = False
    phase_gate: str | None = None
    position: str | None = None
    position_reference_mm: float = 0.0
    denoise: Sequence[str] = ()
    denoise_imfs: int = 1
    name: str | None = None
    command: str | None = None
    span: Span | None = None

    def __post_init__(self) -> None:
        # Frozen all the way down: a list given is kept as a tuple.
        for name in ("inputs", "time_constants_s", "denoise"):
            object.__setattr__(self, name, tuple(getattr(self, name)))


def fit_data(
    data: DataSet | Sequence[DataSet],
    request: FitRequest,
    *,
    progress: Progress | None = None,
) -> FitResult:
    """Identify ``request.output`` from ``request.inputs`` (columns of ``data``) and build the model file.

    The method is looked up by name (:func:`~compd.toolkit.methods.method_named`).
    ``auto`` keeps whichever of the lag bank and the static
    regression fits held-out operating cycles (``cycles``: the column whose
    rising edges start them) best; a lag bank that holds worse than the
    regression is refused unless ``force``. With a phase gate, a position or
    denoising, ``auto`` is ``oe`` (the lag bank has none of them yet).
    ``progress``: told how the order search goes.

    ``data`` may be several experiments (:func:`~compd.files.experiments.load_experiments`):
    inputs are then changes from each file's first values, the lag bank's
    lags and ARX's regressors restart at each file, the model is simulated
    from rest at each file's start, and cross-validation leaves one file out
    (methods ``auto``, ``lagbank``, ``mlr`` and ``arx`` at a given order).

    Raises :class:`~compd.errors.DataFileError` (naming the file, the option or
    column, and the fix) for bad arguments and for data the method cannot fit.
    """
    output, inputs, method, order = request.output, request.inputs, request.method, request.order
    force, phase_gate, position = request.force, request.phase_gate, request.position
    denoise, span = request.denoise, request.span
    starts: tuple[int, ...] = ONE
    # A displacement not zeroed at a file's start is taken as its change from there, per file
    # (not with --from: the samples before it are never fitted and may hold anything).
    columns = [output] if span is None or span.start == 0 else []
    zeroed = [
        zero_displacements(d, columns) for d in ([data] if isinstance(data, DataSet) else data)
    ]
    zeroing_notes = tuple(f"{d.path}: {note}" for d, notes in zeroed for note in notes)
    data = zeroed[0][0] if isinstance(data, DataSet) else [d for d, _ in zeroed]
    if not isinstance(data, DataSet):
        several = list(data)
        if len(several) > 1:
            one_record = method in METHODS and method_named(method).one_record
            _check_several(several[0].path, method, one_record, span, phase_gate, position, denoise)
            stacked = stack(several)
            data, starts = stacked.data, stacked.starts
            span = None  # a whole span of one file (checked above): the whole of every file
        else:
            data = several[0]
    first = 0
    if span is not None:
        data, first = until_stop(data, span), span.start
        if denoise and first:
            raise DataFileError(
                data.path,
                "--denoise with --from is not supported (the denoised fit is measured over "
                "the whole record)",
                where="--from",
                fix="Fit with --denoise and --until only, or without --denoise",
            )
    check_arguments(data, output, inputs, order, method)
    how = method_named(method)
    y = data.column(output)
    if denoise and phase_gate is not None:
        raise DataFileError(
            data.path,
            "--denoise and --phase-gate together are not supported (the gate switches the input "
            "before the TF, so a low-pass baked into the TF would filter the switching too)",
            where="--denoise",
            fix="Fit without --phase-gate, or denoise the column before fitting",
        )
    denoised = denoise_columns(data, denoise, inputs, request.denoise_imfs) if denoise else {}
    changes = {
        column: (denoised[column].emd if column in denoised else data.column(column))
        - start_values(data.column(column), starts)
        for column in inputs
    }
    gate = None
    if phase_gate is not None:
        gate = data.column(phase_gate) > 0.0
    slope = None
    if position is not None:
        check_position(data, position, request.position_reference_mm, output, inputs, phase_gate)
        slope = Position(position, float(request.position_reference_mm))
    if phase_gate is not None and phase_gate in inputs:
        raise DataFileError(
            data.path,
            f"the phase gate {phase_gate!r} is also an input: while it is open the gated input "
            "equals the input, so the heating and cooling sub-models are one regressor and take "
            "cancelling gains (seen: +-154 um/rpm, -1,274,349 % on the next run)",
            where=f"--phase-gate {phase_gate}",
            fix="Gate temperature inputs on the spindle speed, or fit the speed without a gate",
        )
    structured = phase_gate is not None or position is not None or bool(denoise)
    if structured and not how.takes_structure:
        raise DataFileError(
            data.path,
            f"{how.title} does not take --phase-gate, --position or --denoise",
            where=f"--method {method}",
            fix="Use --method oe or arx for those structures, or drop them",
        )
    folds = folds_of(data, operating_signal(data, request.cycles, phase_gate), first, starts)
    select_inputs_first = request.select_inputs_first
    if select_inputs_first and (structured or not how.scores_lag_bank):
        raise DataFileError(
            data.path,
            "--select-inputs chooses inputs for the lag bank",
            where="--select-inputs",
            fix="Use it with --method auto or lagbank, without --phase-gate/--position/--denoise",
        )
    # The regression is always scored: every fit is printed beside it.
    candidates = how.candidates(structured)
    try:
        selection = compare_candidates(
            y,
            changes,
            sample_time_s=data.sample_time_s,
            folds=folds,
            candidates=candidates,
            time_constants_s=request.time_constants_s,
            first_sample=first,
            starts=starts,
            choose_inputs=select_inputs_first,
            input_ranges={c: float(np.ptp(data.column(c))) for c in inputs},
        )
    except ModelError as exc:
        raise DataFileError(data.path, exc.message, where="--time-constants-s") from exc
    steps = list(selection.steps)
    if select_inputs_first:
        changes = {step.input: changes[step.input] for step in steps}
        inputs = list(changes)
    kept = how.kept(selection, structured)
    chosen = kept.name
    if how.judged_against_regression:
        check_against_regression(data, selection, chosen, force)
    prepared = Prepared(
        y,
        changes,
        data.sample_time_s,
        order=order,
        gate=gate,
        position=None if slope is None else data.column(slope.signal) - slope.reference_mm,
        first_sample=first,
        starts=starts,
        progress=progress,
    )
    try:
        identification = kept.identify(prepared, selection.lag_bank)
    except ModelError as exc:
        where = f"--phase-gate {phase_gate}" if "phase-gate" in exc.message else ""
        where = f"--position {position}" if "position" in exc.message else where
        raise DataFileError(data.path, exc.message, where=where) from exc
    model = identification_to_model(
        identification,
        output=output,
        name=request.name or f"{output}-{chosen}",
        gate_signal=phase_gate,
        position=slope,
    )
    denoise_doc = None
    if denoised:
        units = {column: column_unit(data, column) for column in denoised}
        baked = bake_lowpasses(model, identification, data, denoised, units)
        model, identification, denoise_doc = baked.model, baked.identification, baked.doc
    comparison = Comparison.of(output, y[first:], identification.simulated_um[first:])
    try:
        contributions = contributions_of(data, model, starts)
    except ModelError as exc:  # e.g. a pole so near 1 that the static gain is absurd
        raise DataFileError(
            data.path,
            f"the {chosen} model identified on this data cannot run: {exc.message}",
            where=f"--method {chosen}",
            fix="Fit a lower --order or another --method; the default (no --method) is the lag "
            "bank or the static regression, which have no poles to fit",
        ) from exc
    findings = guard_findings(data, model, contributions)
    if not force:
        refuse_errors(
            data,
            findings,
            what="the fitted model is implausible for its own calibration data",
            where=f"--method {chosen}",
        )
    # The thermal zero: the calibration's first values (each experiment's, averaged), which
    # the fit took the inputs as changes from; the daemon starts from it (no "value at start").
    references = {c: float(np.mean(data.column(c)[list(starts)])) for c in inputs}
    model = with_references(model, references, {n: column_unit(data, n) for n in references})
    provenance = fit_provenance(
        data, identification, comparison, request.command, phase_gate, slope, span
    )
    provenance = provenance.model_copy(
        update={"notes": f"{provenance.notes}; {describe_references(model, references)}"}
    )
    held_out = cross_validation_doc(output, selection)
    provenance = provenance.model_copy(
        update={
            "cross_validation": held_out,
            "headline": fit_headline(held_out, model.name, provenance.method),
        }
    )
    if len(starts) > 1:
        notes = (
            f"{provenance.notes}; {len(starts)} experiments (files), each run from rest at its "
            "start with inputs as changes from its first values; no lag spans two files"
        )
        provenance = provenance.model_copy(update={"notes": notes})
    method_notes = kept.notes(selection)
    if method_notes:
        notes = f"{provenance.notes}; {method_notes}"
        provenance = provenance.model_copy(update={"notes": notes})
    if zeroing_notes:
        unzeroed = ", ".join(d.path for d, added in zeroed if added)
        notes = (
            f"{provenance.notes}; {output} not zeroed at the start of {unzeroed}: taken as its "
            "change from its first value there"
        )
        provenance = provenance.model_copy(update={"notes": notes})
    if denoise_doc is not None:
        notes = f"{provenance.notes}; {denoise_note(denoise_doc)}"
        provenance = provenance.model_copy(update={"denoise": denoise_doc, "notes": notes})
    signals = {signal: column_unit(data, signal) for signal in model.signals()}
    text = model_to_yaml(
        model,
        description=f"{output} from {', '.join(inputs)}, identified by compd fit --method {chosen}",
        signals=signals,
        provenance=provenance,
        consistency=consistency_of(data, list(model.signals()), output, starts, span),
        # Issue 35: what the probe update starts from, the calibration's own posterior.
        probe_prior=calibration_probe_priors(model, contributions, y, first),
    )
    return FitResult(
        identification,
        model,
        provenance,
        comparison,
        text,
        selection,
        findings,
        collinear=collinear_groups(np.column_stack(list(changes.values()))[first:], list(changes)),
        input_shares=input_shares(model, contributions),
        selection_steps=steps,
        notes=zeroing_notes,
    )


def consistency_of(
    data: DataSet,
    inputs: Sequence[str],
    output: str,
    starts: Sequence[int] = ONE,
    span: Span | None = None,
) -> ConsistencyDoc | None:
    """How each input follows the other logged signals of the calibration (the daemon's plausibility check).

    Every signal column takes part, not only the model's inputs: the
    daemon reads more than the model uses (a spindle speed predicts the
    spindle's temperature). Displacements, the output and compd's own
    recorded columns (``health.*``, ``status``, ...) do not.
    """
    first = 0 if span is None else span.start
    stop = len(data) if span is None else span.stop
    columns = {
        name: values[first:stop]
        for name, values in data.columns.items()
        if name != output and not is_displacement(name) and not is_recorded_column(name)
    }
    model = fit_consistency(
        columns,
        list(inputs),
        data.sample_time_s,
        starts=[s - first for s in starts if first <= s < stop] or [0],
    )
    return None if model is None else consistency_doc(model)


def _check_several(
    path: str,
    method: str,
    one_record: bool,
    span: Span | None,
    phase_gate: str | None,
    position: str | None,
    denoise: Sequence[str],
) -> None:
    """Refuse what a fit over several files does not do yet, before any work."""
    given = [
        option
        for option, used in (
            ("--from/--until", span is not None and not span.whole),
            ("--phase-gate", phase_gate is not None),
            ("--position", position is not None),
            ("--denoise", bool(denoise)),
            (f"--method {method}", one_record),
        )
        if used
    ]
    if given:
        raise DataFileError(
            path,
            f"{given[0]} works on one record, and several data files were given",
            where=given[0].split()[0],
            fix="Fit several files with --method auto, lagbank, mlr or arx --order N, "
            f"or fit one file with {given[0]}",
        )
