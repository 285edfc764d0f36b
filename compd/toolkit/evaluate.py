"""Running a model file over a data file: the bridge between files and the numeric core.

Brings the model to the data's sample time (exactly, or refused), gathers
the model's signals from the data's columns, picks the initial state and
pairs model outputs with measured columns for comparison.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

import numpy as np

from compd.errors import DataFileError
from compd.files.columns import UNIT_PREFIX
from compd.files.data import DataSet
from compd.files.experiments import Stacked, stack
from compd.files.modelfile import ModelFile
from compd.model.compiled import CompiledModel, ModelState
from compd.model.experiments import ONE
from compd.model.initial import estimate_initial_state
from compd.model.limits import MAX_SAMPLE_TIME_S
from compd.model.metrics import Comparison, fit_percent
from compd.model.run import SimulationResult, simulate
from compd.toolkit.selection import is_displacement
from compd.toolkit.zeroing import zero_displacements

if TYPE_CHECKING:  # compd.toolkit.span builds on this module
    from compd.toolkit.span import Span

InitialState = Literal["steady", "rest", "estimate"]
#: ``init="estimate"`` fits the initial state to the measurement over this much of the record's start.
ESTIMATE_WINDOW_S = 3600.0


@dataclass(frozen=True)
class Evaluation:
    """A model run over a data file, with what was done to make them fit."""

    model_file: ModelFile
    compiled: CompiledModel
    data: DataSet
    result: SimulationResult
    notes: tuple[str, ...]
    #: The part of the record judged (``--from``/``--until``, :mod:`compd.toolkit.span`), if one was asked.
    span: Span | None = None
    #: When this is a later part of a run: that run, from the record's first sample.
    whole: Evaluation | None = None
    #: The first sample of each experiment in :attr:`data` (several files stacked:
    #: :func:`evaluate_each`), where the model started again from its initial state.
    starts: tuple[int, ...] = ONE
    #: Each experiment's file (several files stacked), in the order of :attr:`starts`.
    experiments: tuple[str, ...] = ()

    @property
    def first_sample(self) -> int:
        """Where this part starts in :attr:`whole` (0 without one)."""
        return 0 if self.whole is None or self.span is None else self.span.start

    def predicted(self, output: str) -> np.ndarray:
        return self.result.output(self.compiled, output)


def check_recorded_units(model_file: ModelFile, data: DataSet) -> None:
    """Refuse a column the file records in another unit than the model file reads it in.

    A recording says each column's unit (``unit.<column>``, the config's); a
    model run on degF or mm numbers where it was fitted on degC or um gives
    figures off by a factor that nothing else shows. The daemon refuses such a
    config; the toolkit refuses such a record.
    """
    declared = model_file.signal_units() or {}
    for name in model_file.model.signals():
        recorded = data.metadata.get(UNIT_PREFIX + name)
        model_unit = declared.get(name)
        if recorded is None or model_unit in (None, "-") or _same(recorded) == _same(model_unit):
            continue
        raise DataFileError(
            data.path,
            f"column {name!r} is recorded in {recorded!r}, and model {model_file.path} reads it "
            f"in {model_unit!r}",
            where=f"column {name!r}",
            fix=f"Convert the column to {model_unit!r} (and its unit.{name} line), or use a "
            "model fitted on data in the recorded unit",
        )


#: Spellings of one unit (the daemon's unit check knows more, with their conversions).
_SPELLINGS = {"°C": "degC", "C": "degC", "µm": "um", "μm": "um", "1/min": "rpm", "%": "percent"}


def _same(unit: str) -> str:
    return _SPELLINGS.get(unit, unit)


def check_step(data: DataSet) -> None:
    """Refuse a record whose step no model runs at, naming the data (else a model fitted or run
    at it is refused for its sample time, naming the model): milliseconds in ``time_s``."""
    if data.sample_time_s > MAX_SAMPLE_TIME_S:
        raise DataFileError(
            data.path,
            f"steps {data.sample_time_s:g} s (its median step), longer than the "
            f"{MAX_SAMPLE_TIME_S:g} s a model runs at",
            where="the time column",
            fix="If the time column holds milliseconds, divide it by 1000 (time_s is in seconds); "
            "else resample the record to a step of at most an hour",
        )


def signal_matrix(compiled: CompiledModel, data: DataSet) -> np.ndarray:
    """The model's signals as an (N, n_signals) array; a missing column names the model and the file."""
    missing = [name for name in compiled.signals if not data.has(name)]
    if missing:
        raise DataFileError(
            data.path,
            f"model {compiled.name!r} reads column(s) {missing}, which the file does not have",
            fix=f"Add them, or rename the model's signals to columns the file has: {sorted(data.columns)}",
        )
    # Column-major, so simulate() reads each signal as one contiguous row without a copy.
    return np.vstack([data.column(name) for name in compiled.signals]).T


def evaluate(
    model_file: ModelFile, data: DataSet, *, init: InitialState = "steady", as_logged: bool = False
) -> Evaluation:
    """Compile ``model_file`` at the data's sample time and simulate it over the whole record.

    Every input is taken from its value at the record's first sample, as the
    measured displacement is, whatever the model's references (its thermal
    zero, which the daemon starts from). ``init="steady"`` starts in
    equilibrium with the first sample's signals (no start-up transient); ``"rest"`` starts with all TF states at zero;
    ``"estimate"`` starts from the steady state corrected to fit the measured
    outputs (columns named as the model's outputs) over the first
    :data:`ESTIMATE_WINDOW_S` (:mod:`compd.model.initial`).

    A measured displacement that did not start at 0 is judged as its change
    from its first value (:mod:`compd.toolkit.zeroing`), unless ``as_logged``:
    a part judged from a later sample (``--from``), where the samples before
    it are only run through and may hold anything.
    """
    notes = []
    model_s = model_file.model.sample_time_s
    check_step(data)
    if not np.isclose(model_s, data.sample_time_s, rtol=1e-9, atol=0.0):
        notes.append(
            f"model sample time {model_s:g} s converted exactly to the data's "
            f"{data.sample_time_s:g} s (zero-order hold)"
        )
    # The record's displacement is measured from its start (the probe zeroed there), so its
    # inputs are too: a model's absolute references (its thermal zero) are for the daemon.
    compiled = model_file.compile(data.sample_time_s).referenced_to_start()
    displacements = [
        name
        for name in (*compiled.output_names, *filter(is_displacement, data.columns))
        if name not in compiled.signals
    ]
    if not as_logged:
        data, _ = zero_displacements(data, displacements)
    check_recorded_units(model_file, data)
    signals = signal_matrix(compiled, data)
    state: ModelState = (
        compiled.rest_state(signals[0]) if init == "rest" else compiled.steady_state(signals[0])
    )
    if init == "estimate":
        measured = {o: data.column(o) for o in compiled.output_names if data.has(o)}
        if not measured:
            raise DataFileError(
                data.path,
                f"--init estimate needs the measured outputs, columns named {list(compiled.output_names)}",
                where="--init estimate",
                fix="Name the measured column as the model output, or use --init steady",
            )
        window = max(2, round(ESTIMATE_WINDOW_S / data.sample_time_s))
        state = estimate_initial_state(compiled, signals, measured, state, window)
        notes.append(
            f"initial state estimated from the measurement over the first "
            f"{min(window, len(data)) * data.sample_time_s / 3600:g} h (judge after it with --from)"
        )
    result = simulate(compiled, signals, state)
    return Evaluation(model_file, compiled, data, result, tuple(notes))


def evaluate_each(
    model_file: ModelFile,
    record: Stacked,
    *,
    init: InitialState = "steady",
    as_logged: bool = False,
) -> Evaluation:
    """``model_file`` run over each experiment of ``record`` from its own start, stacked again.

    What ``compd compare`` does with several files, as one evaluation on the
    stacked data (:attr:`Evaluation.starts` says where each run begins), so
    that what judges a residue can judge it over every file at once. One
    experiment is exactly :func:`evaluate`.
    """
    runs = [
        evaluate(model_file, data, init=init, as_logged=as_logged) for data in record.experiments
    ]
    if len(runs) == 1:
        return runs[0]
    results = [run.result for run in runs]
    residuals = [r.residuals for r in results if r.residuals is not None]
    result = SimulationResult(
        outputs=np.concatenate([r.outputs for r in results]),
        contributions=np.concatenate([r.contributions for r in results]),
        final_state=results[-1].final_state,
        residuals=np.concatenate(residuals) if len(residuals) == len(results) else None,
    )
    notes = tuple(dict.fromkeys(note for run in runs for note in run.notes))
    # A run whose measured displacement was zeroed (compd.toolkit.zeroing) is stacked as judged.
    zeroed = any(run.data is not data for run, data in zip(runs, record.experiments, strict=True))
    return Evaluation(
        model_file,
        runs[0].compiled,
        stack([run.data for run in runs]).data if zeroed else record.data,
        result,
        notes,
        starts=record.starts,
        experiments=tuple(data.path for data in record.experiments),
    )


def measured_columns(evaluation: Evaluation, column: str | None = None) -> dict[str, str]:
    """Model output -> measured data column to compare it with.

    Without ``column``: every model output the data has a column of the same
    name for. With ``column``: that output if the model has one of that name,
    else the model's only output.
    """
    outputs = evaluation.compiled.output_names
    data = evaluation.data
    if column is not None:
        data.column(column)  # a clear error when the column is absent
        if column in outputs:
            return {column: column}
        if len(outputs) == 1:
            return {outputs[0]: column}
        raise DataFileError(
            data.path,
            f"--output {column!r} is not one of the model's outputs {list(outputs)} and the "
            "model has several",
            fix="Name the column after the model output it measures",
        )
    pairs = {name: name for name in outputs if data.has(name)}
    if not pairs:
        raise DataFileError(
            data.path,
            f"no column matches the model's outputs {list(outputs)}",
            fix="Pass --output COLUMN to say which column holds the measured displacement",
        )
    return pairs


def compare(evaluation: Evaluation, column: str | None = None) -> list[Comparison]:
    """Model against measurement for each paired output (see :func:`measured_columns`)."""
    return [
        Comparison.of(output, evaluation.data.column(measured), evaluation.predicted(output))
        for output, measured in measured_columns(evaluation, column).items()
    ]


def pooled_comparisons(
    evaluations: Sequence[Evaluation], column: str | None = None
) -> list[Comparison]:
    """Each paired output over several experiments: every file's measurement and prediction end to end.

    Each prediction is its own file's run (from its initial state at that
    file's start), so pooling joins the figures, never the model's state.
    """
    pooled = []
    for output, measured in measured_columns(evaluations[0], column).items():
        pooled.append(
            Comparison.of(
                output,
                np.concatenate([e.data.column(measured) for e in evaluations]),
                np.concatenate([e.predicted(output) for e in evaluations]),
            )
        )
    return pooled


#: ``compare`` says a record seems to start mid-transient when a model started from its
#: estimated state fits the record after :data:`ESTIMATE_WINDOW_S` this many points better.
MID_TRANSIENT_POINTS = 5.0


def mid_transient_note(evaluation: Evaluation, column: str | None = None) -> str | None:
    """A note when ``evaluation`` (started in equilibrium) is unfair to a model with state.

    A file split off a running log, or a run that starts soon after the last,
    begins mid-transient: the default ``--init steady`` then starts every TF
    in equilibrium, so a dynamic model pays for a past the daemon, which
    carries its state, would have known (a static regression has none to
    lose). On the random machines of ``benchmarks/bench_machines.py`` the
    estimated start raised the default lag bank's fit after the first hour by
    5 points or more on 55 % of one-record verify files and 38 % of warm-up
    runs; never a regression's. None when the start is fair, the model has no
    state, the record is shorter than two estimation windows, or its measured
    columns are not named as the model's outputs (``--init estimate`` needs that).
    """
    data = evaluation.data
    window = max(2, round(ESTIMATE_WINDOW_S / data.sample_time_s))
    if evaluation.whole is not None or len(data) < 2 * window:
        return None
    if not any(tf.order > 0 for tf in evaluation.compiled.discrete):
        return None
    # --init estimate reads the measured outputs by the model's names: the others cannot take it.
    pairs = {o: m for o, m in measured_columns(evaluation, column).items() if o == m}
    if not pairs:
        return None
    estimated = evaluate(evaluation.model_file, data, init="estimate")
    for output, measured in pairs.items():
        y = data.column(measured)[window:]
        steady = float(fit_percent(y, evaluation.predicted(output)[window:]))
        started = float(fit_percent(y, estimated.predicted(output)[window:]))
        if np.isfinite(started) and started >= steady + MID_TRANSIENT_POINTS:
            hours, minutes = divmod(round(window * data.sample_time_s / 60.0), 60)
            return (
                f"{output}: the record seems to start mid-transient (split off a running log, or "
                f"soon after a run): from {hours}:{minutes:02d} on, the model fits {steady:.1f} % "
                f"started in equilibrium and {started:.1f} % from a state estimated on the time "
                "before. The daemon carries its state: judge as it runs with --init estimate "
                f"--from {hours}:{minutes:02d}, or on the whole log with --from"
            )
    return None
