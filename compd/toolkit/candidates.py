"""The default ``compd fit``: candidate methods judged by leave-one-cycle-out cross-validation.

A fit on the data it was fitted on proves nothing: on a real machine's 16
collinear temperatures an output-error model reaches 99 % on its calibration
record and triples the drift on the next run. So every fit here is also
judged on operating cycles it was not fitted on (:mod:`compd.model.crossval`),
beside the controllers' static regression on the same inputs, and the
default keeps whichever candidate holds best on held-out cycles: the
regularised lag bank (:mod:`compd.model.lagbank`) or the static regression.

The folds come from an operating signal: ``--cycles SIGNAL``, else the phase
gate, else the first column that looks like spindle speed or power; a record
without one is cut into contiguous blocks.
"""

from __future__ import annotations

import fnmatch
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from threadpoolctl import threadpool_limits

from compd.errors import DataFileError, ModelError
from compd.files.data import DataSet
from compd.files.modelschema import CrossValidationDoc
from compd.model.collinear import contribution_shares
from compd.model.compiled import compile_model, qualified_names
from compd.model.crossval import Folds, blocked_folds, cycle_folds
from compd.model.experiments import ONE, each
from compd.model.guards import Finding, Severity, check_model
from compd.model.identify import Identification, IdentifiedTF
from compd.model.lagbank import (
    DEFAULT_TIME_CONSTANTS_S,
    LagBankFit,
    fit_lag_bank,
    regression_cv,
)
from compd.model.metrics import fit_percent
from compd.model.orderfit import Orders
from compd.model.run import simulate
from compd.model.structure import Model

#: What ``compd fit --method`` accepts; ``auto`` compares lagbank and mlr by cross-validation.
FIT_METHODS = ("auto", "lagbank", "oe", "arx", "mlr")
#: Columns whose rising edges start an operating cycle, in order of preference.
OPERATING_SIGNALS = ("spindle_speed*", "*_rpm", "spindle_power*", "*_kw")


@dataclass(frozen=True)
class CandidateScore:
    """One method's fit % on the data it was fitted on and on held-out cycles (None: not judged)."""

    method: str
    calibration_fit_percent: float
    cv_fit_percent: float | None


@dataclass(frozen=True, eq=False)
class Selection:
    """The folds, every candidate's scores, and the method kept."""

    folds: Folds
    scores: tuple[CandidateScore, ...]
    kept: str
    lag_bank: LagBankFit | None

    def score(self, method: str) -> CandidateScore | None:
        return next((s for s in self.scores if s.method == method), None)


def operating_signal(data: DataSet, explicit: str | None, gate: str | None) -> str | None:
    """The column whose cycles make the folds: ``--cycles``, else the gate, else a speed/power column."""
    if explicit is not None:
        data.column(explicit)  # an unknown column names the file's columns
        return explicit
    if gate is not None:
        return gate
    for pattern in OPERATING_SIGNALS:
        for column in data.columns:
            if fnmatch.fnmatch(column, pattern) and np.ptp(data.column(column)) > 0.0:
                return column
    return None


def folds_of(data: DataSet, signal: str | None) -> Folds:
    """Leave-one-cycle-out folds of ``signal``, or contiguous blocks without one."""
    try:
        if signal is None:
            return blocked_folds(len(data))
        return cycle_folds(data.column(signal), name=signal)
    except ModelError as exc:
        raise DataFileError(data.path, exc.message, where="--cycles") from exc


def compare_candidates(
    y: np.ndarray,
    changes: Mapping[str, np.ndarray],
    *,
    sample_time_s: float,
    folds: Folds,
    candidates: Sequence[str],
    time_constants_s: Sequence[float] = DEFAULT_TIME_CONSTANTS_S,
    first_sample: int = 0,
    starts: Sequence[int] = ONE,
) -> Selection:
    """Score ``candidates`` (of ``lagbank``, ``mlr``) by cross-validation; keep the best held-out fit.

    Only samples from ``first_sample`` on are fitted and scored; the models run from the record's
    start (from each experiment's, with several ``starts``).
    """
    # Hundreds of small (80 x 80) solves: BLAS threads only spin against each other there,
    # and on a busy 2-core PC they made the search 15x slower (0.25 s -> 3.4 s CPU).
    with threadpool_limits(limits=1, user_api="blas"):
        fitted = np.arange(len(y)) >= first_sample
        return _select(
            y, changes, sample_time_s, folds, candidates, time_constants_s, fitted, starts
        )


def _select(
    y: np.ndarray,
    changes: Mapping[str, np.ndarray],
    sample_time_s: float,
    folds: Folds,
    candidates: Sequence[str],
    time_constants_s: Sequence[float],
    fitted: np.ndarray,
    starts: Sequence[int],
) -> Selection:
    u = np.column_stack([np.asarray(v, dtype=float) for v in changes.values()])
    scores = []
    lag_bank = None
    if "lagbank" in candidates:
        lag_bank = fit_lag_bank(
            y,
            u,
            sample_time_s=sample_time_s,
            folds=folds,
            fitted=fitted,
            time_constants_s=time_constants_s,
            starts=starts,
        )
        scores.append(CandidateScore("lagbank", lag_bank.fit_percent, lag_bank.cv_fit_percent))
    gains, regression_cv_percent = regression_cv(y, u, folds, fitted)
    regression_fit = float(fit_percent(y[fitted], (u @ gains)[fitted]))
    scores.append(CandidateScore("mlr", regression_fit, regression_cv_percent))
    judged = [s for s in scores if s.method in candidates]
    kept = max(judged, key=lambda s: s.cv_fit_percent or -np.inf).method
    return Selection(folds, tuple(scores), kept, lag_bank)


#: An extension must raise the held-out fit by this many points, or ``compd extend`` does not add it.
EXTEND_MARGIN_POINTS = 2.0
#: Forward selection stops when the next input adds less than this to the held-out fit (points).
SELECTION_MIN_GAIN_POINTS = 1.0


@dataclass(frozen=True)
class SelectionStep:
    """One forward-selection step: the input added and the held-out fit with it."""

    input: str
    cv_fit_percent: float


def select_inputs(
    y: np.ndarray,
    changes: Mapping[str, np.ndarray],
    *,
    sample_time_s: float,
    folds: Folds,
    time_constants_s: Sequence[float] = DEFAULT_TIME_CONSTANTS_S,
    first_sample: int = 0,
    min_gain_points: float = SELECTION_MIN_GAIN_POINTS,
    starts: Sequence[int] = ONE,
) -> list[SelectionStep]:
    """Inputs added one at a time, each the one that raises the lag bank's held-out fit most.

    Stops when the best next input adds less than ``min_gain_points``. The
    choice is made with the same folds that score it, so its figure is
    optimistic: it says which sensors carry the information, and the
    cross-validated fit of the final model is reported beside the regression's.
    """
    names = list(changes)
    u = np.column_stack([np.asarray(changes[n], dtype=float) for n in names])
    fitted = np.arange(len(y)) >= first_sample
    steps: list[SelectionStep] = []
    chosen: list[int] = []
    best = -np.inf
    with threadpool_limits(limits=1, user_api="blas"):
        while len(chosen) < len(names):
            trials = {}
            for j in (j for j in range(len(names)) if j not in chosen):
                bank = fit_lag_bank(
                    y,
                    u[:, [*chosen, j]],
                    sample_time_s=sample_time_s,
                    folds=folds,
                    fitted=fitted,
                    time_constants_s=time_constants_s,
                    starts=starts,
                )
                trials[j] = bank.cv_fit_percent if bank.cv_fit_percent is not None else -np.inf
            j = max(trials, key=trials.__getitem__)
            if trials[j] < best + min_gain_points:
                break
            best = trials[j]
            chosen.append(j)
            steps.append(SelectionStep(names[j], float(best)))
    return steps


def lag_bank_identification(
    fit: LagBankFit, inputs: Sequence[str], sample_time_s: float
) -> Identification:
    """The lag bank as identified channels: per input, a first-order TF at each time constant."""
    channels = [
        IdentifiedTF(name, tf, gated=False, time_constant_s=tau)
        for name, tfs in zip(inputs, fit.channel_tfs(sample_time_s), strict=True)
        for tf, tau in zip(tfs, fit.time_constants_s, strict=True)
    ]
    orders = Orders(
        na=1,
        nb=tuple(len(c.tf.num) for c in channels),
        nf=tuple(c.tf.order for c in channels),
        nk=tuple(c.tf.nk for c in channels),
    )
    return Identification(
        method="lagbank",
        channels=tuple(channels),
        sample_time_s=sample_time_s,
        fit_percent=fit.fit_percent,
        validation_fit_percent=None,
        orders=orders,
        simulated_um=fit.predicted_um,
    )


def describe_lag_bank(fit: LagBankFit) -> str:
    """One line: the settings cross-validation chose."""
    taus = ", ".join(f"{t:g}" for t in fit.time_constants_s)
    return (
        f"lag bank at time constants [{taus}] s on the inputs' {fit.n_modes} leading principal "
        f"direction(s), ridge weight {fit.ridge_weight:.1e}"
    )


Contributions = dict[str, dict[str, np.ndarray]]


def contributions_of(data: DataSet, model: Model, starts: Sequence[int] = ONE) -> Contributions:
    """Each sub-model's contribution (um) over ``data``, run from rest at the record's start.

    With several ``starts`` (stacked experiments), from rest at each experiment's start.
    """
    compiled = compile_model(model, data.sample_time_s)
    signals = np.column_stack([data.column(name) for name in compiled.signals])

    def run(part: np.ndarray) -> np.ndarray:
        return simulate(compiled, part, compiled.rest_state(part[0])).contributions

    terms = each(run, signals, starts)
    contributions: Contributions = {}
    for index, qualified in enumerate(qualified_names(compiled)):
        output, _, sub = qualified.partition("/")
        contributions.setdefault(output, {})[sub] = terms[:, index]
    return contributions


def input_shares(model: Model, contributions: Contributions) -> dict[str, float]:
    """Each input signal's share of the model's contribution RMS (its sub-models summed), largest first."""
    per_input: dict[str, np.ndarray] = {}
    for output in model.outputs:
        for sub in output.submodels:
            term = contributions.get(output.name, {}).get(sub.name)
            if term is not None:
                per_input[sub.input.signal] = per_input.get(sub.input.signal, 0.0) + term
    if not per_input:
        return {}
    shares = contribution_shares(np.column_stack(list(per_input.values())))
    return dict(sorted(zip(per_input, map(float, shares), strict=True), key=lambda kv: -kv[1]))


def guard_findings(
    data: DataSet, model: Model, contributions: Contributions | None = None
) -> list[Finding]:
    """The guard rails (:mod:`compd.model.guards`) on ``model`` over the record it was fitted on."""
    if contributions is None:
        contributions = contributions_of(data, model)
    ranges = {
        column: (float(np.min(values)), float(np.max(values)))
        for column, values in data.columns.items()
    }
    return check_model(
        model,
        ranges=ranges,
        record_s=len(data) * data.sample_time_s,
        contributions=contributions,
    )


def refuse_errors(data: DataSet, findings: Sequence[Finding], *, what: str, where: str) -> None:
    """Raise naming every guard-rail error in ``findings`` (``what``: the model or sub-model judged)."""
    errors = [f for f in findings if f.severity is Severity.ERROR]
    if errors:
        raise DataFileError(
            data.path,
            f"{what}:\n  " + "\n  ".join(f.describe() for f in errors),
            where=where,
            fix="Follow the fixes above, or --force to write it anyway",
        )


def check_against_regression(data: DataSet, selection: Selection, chosen: str, force: bool) -> None:
    """Refuse a model that holds worse on held-out cycles than the static regression (unless forced)."""
    score, regression = selection.score(chosen), selection.score("mlr")
    if force or score is None or regression is None or chosen == "mlr":
        return
    if score.cv_fit_percent is None or regression.cv_fit_percent is None:
        return
    if score.cv_fit_percent < regression.cv_fit_percent:
        raise DataFileError(
            data.path,
            f"the {chosen} model fits held-out operating cycles worse than the static regression "
            f"on the same inputs ({score.cv_fit_percent:.1f} % vs {regression.cv_fit_percent:.1f} "
            f"%; {selection.folds.describe()}): it would compensate worse than the controller's "
            "built-in regression",
            where=f"--method {chosen}",
            fix="Use --method auto (keeps the better), --select-inputs, or --force to write it",
        )


def cross_validation_doc(output: str, selection: Selection) -> CrossValidationDoc:
    return CrossValidationDoc(
        folds=selection.folds.describe(),
        kept=selection.kept,
        fit_percent={
            s.method: s.cv_fit_percent for s in selection.scores if s.cv_fit_percent is not None
        },
        calibration_fit_percent={s.method: s.calibration_fit_percent for s in selection.scores},
        output=output,
    )
