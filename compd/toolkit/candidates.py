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

import dataclasses
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
from compd.model.crossval import Folds, blocked_folds, cross_validated_prediction, cycle_folds
from compd.model.experiments import ONE, each
from compd.model.guards import Finding, Severity, check_model
from compd.model.identify import Identification, IdentifiedTF
from compd.model.lagbank import DEFAULT_TIME_CONSTANTS_S, LagBankFit, regression_cv
from compd.model.metrics import fit_percent
from compd.model.nested import nested_prediction, scored_fit_percent
from compd.model.orderfit import Orders
from compd.model.run import simulate
from compd.model.shrinkbank import ShrunkBank, regression_plausible
from compd.model.structure import Model

#: What ``compd fit --method`` accepts; ``auto`` compares lagbank and mlr by cross-validation.
FIT_METHODS = ("auto", "lagbank", "oe", "arx", "mlr")
#: Columns whose rising edges start an operating cycle, in order of preference.
OPERATING_SIGNALS = ("spindle_speed*", "*_rpm", "spindle_power*", "*_kw")


#: An extension must raise the held-out fit by this many points, or ``compd extend`` does not add it.
EXTEND_MARGIN_POINTS = 2.0
#: Forward selection stops when the next input adds less than this to the held-out fit (points).
SELECTION_MIN_GAIN_POINTS = 1.0


@dataclass(frozen=True)
class SelectionStep:
    """One forward-selection step: the input added and the held-out fit with it."""

    input: str
    cv_fit_percent: float


@dataclass(frozen=True)
class CandidateScore:
    """One method's fit % on the data it was fitted on, on held-out folds, and nested (None: not judged).

    ``cv_fit_percent``: held-out folds, the method's settings chosen by the
    same folds (optimistic); ``nested_fit_percent``: its settings chosen inside
    each training set only (:mod:`compd.model.nested`): what to expect on new
    data of the same kind.
    """

    method: str
    calibration_fit_percent: float
    cv_fit_percent: float | None
    nested_fit_percent: float | None = None

    @property
    def expected_percent(self) -> float | None:
        """The honest figure: nested, else (too few folds to nest) the cross-validated one."""
        return (
            self.nested_fit_percent if self.nested_fit_percent is not None else self.cv_fit_percent
        )


@dataclass(frozen=True, eq=False)
class Selection:
    """The folds, every candidate's scores, and the method kept."""

    folds: Folds
    scores: tuple[CandidateScore, ...]
    kept: str
    lag_bank: LagBankFit | None  # on the chosen inputs (all, or those of ``steps``)
    #: With input selection: the inputs in the order forward selection added them.
    steps: tuple[SelectionStep, ...] = ()

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
    choose_inputs: bool = False,
    fitted: np.ndarray | None = None,
    new_recordings: bool = False,
) -> Selection:
    """Score ``candidates`` (of ``lagbank``, ``mlr``) by nested cross-validation; keep the best.

    The kept method is the one with the best nested fit (:class:`CandidateScore`);
    on a tie, or when the lag bank's is lower, the static regression. Only
    samples from ``first_sample`` on are fitted and scored; the models run
    from the record's start (from each experiment's, with several ``starts``).
    ``choose_inputs``: the lag bank's inputs by forward selection
    (:func:`forward_selection`), redone inside each training set for the
    nested figure; the regression is then scored on the chosen inputs.
    ``fitted``: a mask of the samples to fit and score (default all), with ``first_sample``.
    ``new_recordings``: judge each held-out fold of one record as a new recording
    (:class:`~compd.model.shrinkbank.ShrunkBank`) instead of the record continued.
    """
    # Many small solves: BLAS threads only spin against each other there (on a busy
    # 2-core PC they made the search 15x slower).
    with threadpool_limits(limits=1, user_api="blas"):
        mask = np.ones(len(y), dtype=bool) if fitted is None else np.asarray(fitted, dtype=bool)
        fitted = mask & (np.arange(len(y)) >= first_sample)
        names = list(changes)
        u = np.column_stack([np.asarray(v, dtype=float) for v in changes.values()])
        scores = []
        lag_bank = None
        nested = None
        steps: tuple[SelectionStep, ...] = ()
        if "lagbank" in candidates or choose_inputs:
            bank = ShrunkBank(
                y,
                u,
                sample_time_s=sample_time_s,
                folds=folds,
                fitted=fitted,
                time_constants_s=time_constants_s,
                starts=starts,
                new_recordings=new_recordings,
            )

            def chosen(train: np.ndarray) -> list[int] | None:
                return [j for j, _ in forward_selection(bank, train)] if choose_inputs else None

            inputs = chosen(fitted)
            if inputs is not None:
                steps = tuple(
                    SelectionStep(names[j], s) for j, s in forward_selection(bank, fitted)
                )
                u = u[:, inputs]
            lag_bank = _restricted(bank.fit(fitted, inputs), inputs)
            nested = nested_prediction(
                lambda train: bank.fresh_prediction(bank.fit(train, chosen(train))), folds, fitted
            )
            scores.append(
                CandidateScore(
                    "lagbank",
                    lag_bank.fit_percent,
                    lag_bank.cv_fit_percent,
                    scored_fit_percent(bank.fresh_y, nested),
                )
            )
            fresh_u, fresh_y = bank.fresh_u, bank.fresh_y
        else:
            fresh_u, fresh_y = u, y
        if steps:
            fresh_u = fresh_u[:, [names.index(step.input) for step in steps]]
        gains, _ = regression_cv(y, u, folds, fitted)
        regression_fit = float(fit_percent(y[fitted], (u @ gains)[fitted]))
        baseline = cross_validated_prediction(
            lambda train: fresh_u @ np.linalg.lstsq(u[train], y[train], rcond=None)[0],
            folds,
            fitted,
        )
        # The regression has no settings to choose: its nested figure is its cross-validated one.
        regression_cv_percent = scored_fit_percent(fresh_y, baseline)
        scores.append(
            CandidateScore("mlr", regression_fit, regression_cv_percent, regression_cv_percent)
        )
    judged = [s for s in scores if s.method in candidates]
    if len(judged) > 1 and not regression_plausible(y[fitted], u[fitted], gains):
        # The guard rails would refuse the regression (collinear inputs balanced against each
        # other); the lag bank, plausible by construction, is the model to write.
        judged = [s for s in judged if s.method != "mlr"]
    kept = max(judged, key=_preference).method
    if kept == "lagbank" and "mlr" in {s.method for s in judged}:
        kept = "lagbank" if _consistently_better(fresh_y, nested, baseline, folds) else "mlr"
    return Selection(folds, tuple(scores), kept, lag_bank, steps)


#: The lag bank is kept over the regression only when its nested improvement, fold by fold,
#: is at least this many standard errors above zero.
MARGIN_STANDARD_ERRORS = 1.0


def _consistently_better(
    y: np.ndarray, nested: np.ndarray | None, baseline: np.ndarray, folds: Folds
) -> bool:
    """Whether the lag bank's nested errors beat the regression's by a standard error, fold by fold.

    The one-standard-error rule again, now between methods: a dynamic model
    that wins on two folds and loses on two is a coin toss that travels worse.
    """
    if nested is None:
        return True
    gains = []
    for fold in range(folds.n_folds):
        held = (folds.labels == fold) & np.isfinite(nested) & np.isfinite(baseline)
        if held.any():
            gains.append(
                float(
                    np.sum((y[held] - baseline[held]) ** 2) - np.sum((y[held] - nested[held]) ** 2)
                )
            )
    if len(gains) < 2:
        return True
    spread = float(np.std(gains, ddof=1) * np.sqrt(len(gains)))
    return float(np.sum(gains)) > MARGIN_STANDARD_ERRORS * spread


def _restricted(fit: LagBankFit, inputs: Sequence[int] | None) -> LagBankFit:
    """``fit`` with the gains of ``inputs`` only (None: all), in that order."""
    if inputs is None:
        return fit
    return dataclasses.replace(fit, gains=fit.gains[list(inputs)], n_modes=len(inputs))


def _preference(score: CandidateScore) -> tuple[float, bool]:
    """Sort key: the honest figure first; on a tie the static regression (it has nothing to fit)."""
    expected = score.expected_percent
    return (-np.inf if expected is None else round(expected, 6), score.method == "mlr")


def forward_selection(
    bank: ShrunkBank, train: np.ndarray, min_gain_points: float = SELECTION_MIN_GAIN_POINTS
) -> list[tuple[int, float]]:
    """Input indices in the order forward selection adds them on ``train``, each with its held-out fit."""
    chosen: list[int] = []
    path: list[tuple[int, float]] = []
    best = -np.inf
    while len(chosen) < bank.n_inputs:
        trials = {}
        for j in (j for j in range(bank.n_inputs) if j not in chosen):
            score = bank.fit(train, [*chosen, j]).cv_fit_percent
            trials[j] = -np.inf if score is None else score
        j = max(trials, key=trials.__getitem__)
        if trials[j] < best + min_gain_points:
            break
        best = trials[j]
        chosen.append(j)
        path.append((j, float(best)))
    return path


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
        f"lag bank at time constants [{taus}] s on {fit.n_modes} input(s): the static "
        f"regression plus lags shrunk toward it, weight {fit.ridge_weight:.1e} (one standard "
        "error rule)"
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
    """Refuse a model expected to hold worse on new data than the static regression (unless forced)."""
    score, regression = selection.score(chosen), selection.score("mlr")
    if force or score is None or regression is None or chosen == "mlr":
        return
    mine, baseline = score.expected_percent, regression.expected_percent
    if mine is None or baseline is None:
        return
    if mine < baseline:
        raise DataFileError(
            data.path,
            f"the {chosen} model fits held-out operating cycles worse than the static regression "
            f"on the same inputs ({mine:.1f} % vs {baseline:.1f} %, settings chosen inside each "
            f"training set; {selection.folds.describe()}): it would compensate worse than the "
            "controller's built-in regression",
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
        nested_fit_percent={
            s.method: s.nested_fit_percent
            for s in selection.scores
            if s.nested_fit_percent is not None
        },
        calibration_fit_percent={s.method: s.calibration_fit_percent for s in selection.scores},
        output=output,
    )
