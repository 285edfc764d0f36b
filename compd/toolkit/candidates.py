"""The default ``compd fit``: folds, the kept candidate as a model, and the checks around it.

A fit on the data it was fitted on proves nothing: on a real machine's 16
collinear temperatures an output-error model reaches 99 % on its calibration
record and triples the drift on the next run. So every fit is also judged on
operating cycles it was not fitted on (:mod:`compd.model.crossval`), beside
the controllers' static regression on the same inputs; which candidate is
kept is :mod:`compd.toolkit.nestedselect`'s choice.

The folds come from an operating signal: ``--cycles SIGNAL``, else the phase
gate, else the first column that looks like spindle speed or power; a record
without one is cut into contiguous blocks.
"""

from __future__ import annotations

import fnmatch
from collections.abc import Sequence

import numpy as np

from compd.errors import DataFileError, ModelError
from compd.files.data import DataSet
from compd.files.modelschema import CrossValidationDoc
from compd.model.collinear import contribution_shares
from compd.model.compiled import compile_model, qualified_names
from compd.model.crossval import (
    MIN_FOLD_SAMPLES,
    Folds,
    blocked_folds,
    cycle_folds,
    experiment_folds,
)
from compd.model.experiments import ONE, each
from compd.model.guards import Finding, Severity, check_model
from compd.model.identify import Identification, IdentifiedTF
from compd.model.lagbank import LagBankFit
from compd.model.orderfit import Orders
from compd.model.run import simulate
from compd.model.structure import Model
from compd.toolkit.nestedselect import BASELINE, LAG_BANK, Selection

#: Columns whose rising edges start an operating cycle, in order of preference.
OPERATING_SIGNALS = ("spindle_speed*", "*_rpm", "spindle_power*", "*_kw")


#: An extension must raise the held-out fit by this many points, or ``compd extend`` does not add it.
EXTEND_MARGIN_POINTS = 2.0


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


def folds_of(
    data: DataSet, signal: str | None, first_sample: int = 0, starts: Sequence[int] = ONE
) -> Folds:
    """Leave-one-cycle-out folds of ``signal``, or contiguous blocks without one.

    Several experiments stacked (``starts``): leave one experiment out instead.
    Only samples from ``first_sample`` on are fitted and judged (``--from``).
    When the whole record's folds leave that part in fewer than
    :data:`MIN_SCORED_FOLDS` of them (the last hours of a long log, inside its
    last cycle), the folds are made of that part alone; the samples before it
    join its first fold (they are run through, never scored).
    """
    if len(starts) > 1:
        return experiment_folds(len(data), starts)
    whole = _folds(data, signal, np.arange(len(data)))
    if first_sample == 0 or _scored_folds(whole, first_sample) >= MIN_SCORED_FOLDS:
        return whole
    part = _folds(data, signal, np.arange(first_sample, len(data)))
    labels = np.concatenate([np.zeros(first_sample, dtype=int), part.labels])
    return Folds(labels, f"{part.kind} of the scored part")


#: Fewest folds that must hold scored samples for the whole record's folds to be used.
MIN_SCORED_FOLDS = 3


def _folds(data: DataSet, signal: str | None, rows: np.ndarray) -> Folds:
    try:
        if signal is None:
            return blocked_folds(rows.size)
        return cycle_folds(data.column(signal)[rows], name=signal)
    except ModelError as exc:
        raise DataFileError(data.path, exc.message, where="--cycles") from exc


def _scored_folds(folds: Folds, first_sample: int) -> int:
    """How many folds hold at least one cross-validation block's worth of scored samples."""
    counts = np.bincount(folds.labels[first_sample:], minlength=folds.n_folds)
    return int(np.sum(counts >= MIN_FOLD_SAMPLES))


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
        method=LAG_BANK,
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
    score, regression = selection.score(chosen), selection.score(BASELINE)
    if force or score is None or regression is None or chosen == BASELINE:
        return
    mine, baseline = score.held_out_percent, regression.held_out_percent
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
        fold_spread_percent={s.method: s.spread_percent for s in selection.scores},
        fold_median_percent={
            s.method: s.median_fold_percent
            for s in selection.scores
            if s.median_fold_percent is not None
        },
        calibration_fit_percent={s.method: s.calibration_fit_percent for s in selection.scores},
        output=output,
    )
