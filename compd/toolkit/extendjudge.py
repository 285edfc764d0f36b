"""Whether an extension earns its place: judged by what it does to the error on held-out folds.

``compd extend`` and ``compd diagnose`` ask the same question of a candidate
signal: fit the residue by a regularised lag bank on the signal
(:mod:`compd.model.lagbank`) on all but one operating cycle at a time,
predict the held-out cycle, and compare the model's error there without and
with it. The rule (:data:`RULE`) is stated in terms of the error, not of fit
points: near 90 % every real gain is a few points, near 10 % two points are
noise. An extension is kept when it removes at least
:data:`MIN_ERROR_REMOVED_PERCENT` of the remaining held-out error (pooled
RMS) and lowers the error on most of the folds.

Sub-models that an earlier ``extend`` fitted on the *same record*
(:func:`same_record_extensions`) are re-identified together with the new
signal: fitted one after the other, the first signal takes a share of the
second effect it cannot carry to another run (cutting heat and a moving
coolant temperature at once: 73.6 % on an unseen run one after the other,
91.7 % together). The judgement then compares the earlier signals alone with
the earlier signals and the new one, both cross-validated on the same folds.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from compd.files.data import DataSet
from compd.files.modelfile import ModelFile
from compd.files.yamlplace import resolve_path
from compd.model.crossval import Folds
from compd.model.diagnose import MIN_DIAGNOSED_SAMPLES, diagnosis_blocks
from compd.model.experiments import ONE, spans, start_values
from compd.model.lagbank import LagBankFit, fit_lag_bank
from compd.model.lagscore import fit_candidate, time_constant_bank
from compd.model.metrics import fit_percent
from compd.toolkit.candidates import folds_of, operating_signal
from compd.toolkit.evaluate import Evaluation

#: An extension must remove at least this share of the remaining held-out error (RMS), in %.
MIN_ERROR_REMOVED_PERCENT = 10.0
#: The rule, as printed with every judgement.
RULE = (
    f"an extension is kept when it removes at least {MIN_ERROR_REMOVED_PERCENT:g} % of the "
    "remaining error on held-out folds (and as much beyond what a constant offset would) and "
    "lowers it on most of them"
)
#: Two candidates whose extended fits differ by less than this many standard errors of the
#: per-fold differences are presented as tied.
TIE_STANDARD_ERRORS = 2.0
#: Of two tied signals, one follows the other when lags of it reproduce at least this share (%)
#: of the follower's changes and :data:`FOLLOW_MARGIN_POINTS` more than the reverse.
FOLLOW_MIN_PERCENT = 50.0
FOLLOW_MARGIN_POINTS = 20.0


@dataclass(frozen=True)
class HeldOut:
    """The model's error on held-out folds without and with a (regularised) sub-model on a signal."""

    folds: str
    before: float
    """Fit % on the held-out parts without the signal."""
    after: float
    """Fit % with it."""
    rms_before_um: float = float("nan")
    rms_after_um: float = float("nan")
    fold_rms_before_um: tuple[float, ...] = ()
    fold_rms_after_um: tuple[float, ...] = ()
    rms_offset_um: float = float("nan")
    """The held-out error with a constant offset instead (each fold's from the others' mean)."""

    @property
    def rise_points(self) -> float:
        return self.after - self.before

    @property
    def error_removed_percent(self) -> float:
        """``100 (1 - RMS_after / RMS_before)`` of the pooled held-out error."""
        if not self.rms_before_um > 0.0:
            return 0.0
        return 100.0 * (1.0 - self.rms_after_um / self.rms_before_um)

    @property
    def folds_improved(self) -> int:
        return sum(
            a < b for a, b in zip(self.fold_rms_after_um, self.fold_rms_before_um, strict=True)
        )

    @property
    def n_folds(self) -> int:
        return len(self.fold_rms_before_um)

    @property
    def beyond_offset_percent(self) -> float:
        """``100 (1 - RMS_after / RMS_offset)``: what the signal removes beyond a constant offset."""
        if not self.rms_offset_um > 0.0:
            return self.error_removed_percent
        return 100.0 * (1.0 - self.rms_after_um / self.rms_offset_um)

    @property
    def accepted(self) -> bool:
        """:data:`RULE`: enough of the error removed, more than an offset would, on most folds."""
        return (
            self.error_removed_percent >= MIN_ERROR_REMOVED_PERCENT
            and not self.beyond_offset_percent < MIN_ERROR_REMOVED_PERCENT
            and 2 * self.folds_improved > self.n_folds
        )

    def describe(self) -> str:
        """The figures of the rule in one clause."""
        return (
            f"removes {self.error_removed_percent:.0f} % of the remaining error on held-out folds "
            f"(RMS {self.rms_before_um:.3g} -> {self.rms_after_um:.3g} um, fit "
            f"{self.before:.1f} % -> {self.after:.1f} %, {self.rise_points:+.1f} points) and lowers "
            f"it on {self.folds_improved} of {self.n_folds} folds ({self.folds})"
            + (
                f"; a constant offset alone would leave {self.rms_offset_um:.3g} um, so the "
                f"signal itself removes {self.beyond_offset_percent:.0f} %"
                if self.beyond_offset_percent < MIN_ERROR_REMOVED_PERCENT
                else ""
            )
        )


@dataclass(frozen=True)
class Prior:
    """The sub-models an earlier extension fitted on this record, re-identified with the new signal."""

    signals: tuple[str, ...]
    submodels: tuple[str, ...]
    effects: dict[str, str]
    """Signal -> the effect its sub-models were added for."""


NO_PRIOR = Prior((), (), {})


def same_record_extensions(parent: ModelFile, output: str, data: DataSet, signal: str) -> Prior:
    """The parent's extensions of ``output`` fitted on ``data``'s file, other than on ``signal``.

    An extension on another record stays as it is: refitting it here would
    lose what that record taught it. A recorded path is relative to the
    model file's folder (:mod:`compd.files.provenancepaths`); an unsaved
    model's, as the command named it.
    """
    here = _resolved(data.path)
    folder = Path(parent.path).parent if parent.path and Path(parent.path).exists() else Path()
    present = {s.name: s for o in parent.model.outputs if o.name == output for s in o.submodels}
    signals: list[str] = []
    submodels: list[str] = []
    effects: dict[str, str] = {}
    for ext in parent.doc.provenance.extensions:
        if _resolved(ext.data) != here and _resolved(ext.data, folder) != here:
            continue
        for name in ext.submodels:
            sub = present.get(name)
            if sub is None or sub.input.signal == signal or name in submodels:
                continue
            submodels.append(name)
            if sub.input.signal not in signals:
                signals.append(sub.input.signal)
                effects[sub.input.signal] = sub.effect.split(" (lag ")[0]
    return Prior(tuple(signals), tuple(submodels), effects)


def without_prior(evaluation: Evaluation, output: str, prior: Prior) -> np.ndarray:
    """The parent's prediction of ``output`` without the prior's sub-models (superposition)."""
    predicted = np.array(evaluation.predicted(output), dtype=float)
    compiled = evaluation.compiled
    owners = compiled.output_matrix.argmax(axis=0)
    for i, sub in enumerate(compiled.submodels):
        if sub.name in prior.submodels and compiled.output_names[owners[i]] == output:
            predicted -= evaluation.result.contributions[:, i]
    return predicted


def judge_signal(
    data: DataSet,
    measured: np.ndarray,
    predicted: np.ndarray,
    signal: str,
    *,
    prior: Prior = NO_PRIOR,
    first_sample: int = 0,
    folds: Folds | None = None,
    starts: Sequence[int] = ONE,
) -> tuple[HeldOut, LagBankFit]:
    """How a regularised sub-model on ``signal`` changes the error on parts of ``data`` it never saw.

    ``predicted`` is the model without ``prior``'s sub-models; the residue is
    fitted by a lag bank on ``prior``'s signals (before) and on those and
    ``signal`` (after), leaving one operating cycle (or block) out at a time;
    with several experiments stacked (``starts``), one experiment (file) out
    at a time, every lag from rest at each start.
    Returns the judgement and the lag bank on all signals fitted on every
    scored sample, which ``--method lagbank`` adds as the sub-models.
    """
    if folds is None:
        folds = folds_of(data, operating_signal(data, None, None), first_sample, starts)
    residue = measured - predicted
    fitted = np.arange(len(residue)) >= first_sample
    changes = np.column_stack(
        [data.column(s) - start_values(data.column(s), starts) for s in (*prior.signals, signal)]
    )
    with threadpool_limits(limits=1, user_api="blas"):
        after = fit_lag_bank(
            residue,
            changes,
            sample_time_s=data.sample_time_s,
            folds=folds,
            fitted=fitted,
            starts=starts,
        )
        before = (
            fit_lag_bank(
                residue,
                changes[:, :-1],
                sample_time_s=data.sample_time_s,
                folds=folds,
                fitted=fitted,
                starts=starts,
            ).cv_predicted_um
            if prior.signals
            else np.zeros_like(residue)
        )
    assert after.cv_predicted_um is not None and before is not None
    held = np.isfinite(after.cv_predicted_um) & np.isfinite(before) & fitted
    error_before = residue - before
    error_after = residue - after.cv_predicted_um
    labels = folds.labels[held]
    fold_rms = [
        tuple(_rms(e[held][labels == k]) for k in np.unique(labels))
        for e in (error_before, error_after)
    ]
    offset = np.zeros_like(residue)
    for k in range(folds.n_folds):
        inside = folds.labels == k
        training = fitted & ~inside & np.isfinite(before)
        if training.any():
            offset[inside] = np.mean((residue - before)[training])
    error_offset = error_before - offset
    judged = HeldOut(
        folds=folds.describe(),
        before=float(fit_percent(measured[held], measured[held] - error_before[held])),
        after=float(fit_percent(measured[held], measured[held] - error_after[held])),
        rms_before_um=_rms(error_before[held]),
        rms_after_um=_rms(error_after[held]),
        fold_rms_before_um=fold_rms[0],
        fold_rms_after_um=fold_rms[1],
        rms_offset_um=_rms(error_offset[held]),
    )
    return judged, after


def tied(first: HeldOut, second: HeldOut) -> bool:
    """Whether ``first``'s lead over ``second`` is within the noise of the folds.

    The per-fold differences of the held-out error with each extension: the
    lead is real only if the first is better on most folds and the mean
    difference exceeds :data:`TIE_STANDARD_ERRORS` standard errors of them.
    """
    a, b = np.asarray(first.fold_rms_after_um), np.asarray(second.fold_rms_after_um)
    if a.size != b.size or a.size < 2:
        return False
    diff = b - a  # > 0 where the first is better
    if 2 * int(np.sum(diff > 0)) <= diff.size:
        return True
    spread = float(np.std(diff, ddof=1)) / float(np.sqrt(diff.size))
    return float(np.mean(diff)) <= TIE_STANDARD_ERRORS * spread


def ranked(judged: Mapping[str, HeldOut]) -> list[str]:
    """Signals best first by the extended model's held-out fit."""
    return sorted(judged, key=lambda s: -judged[s].after)


@dataclass(frozen=True)
class Ranking:
    """Judged signals in order, and whether the first two are tied (and who follows whom)."""

    order: tuple[str, ...]
    tied: tuple[str, ...] = ()
    """The first two, when their extensions are within the noise of the folds (:func:`tied`)."""
    follows_percent: tuple[float, float] | None = None
    """For a tie: how much of the second's changes lags of the first reproduce, and the reverse."""


def rank_judged(
    judged: Mapping[str, HeldOut],
    data: DataSet,
    first_sample: int = 0,
    starts: Sequence[int] = ONE,
) -> Ranking:
    """Best extended model first; of two tied ones, the one the other follows first.

    When the data cannot tell two signals apart, one of them is usually a
    temperature that follows the other (a motor temperature follows the
    spindle power, the air at the door follows the door) and also carries
    heat the model already explains or that moves differently on the next
    run. Which follows which is visible in the signals themselves: lags of
    the cause reproduce the follower, not the other way round (a first-order
    lag cannot make a step). So the pair is ordered cause first when the
    lags of one reproduce at least :data:`FOLLOW_MIN_PERCENT` of the other's
    changes on held-out blocks and :data:`FOLLOW_MARGIN_POINTS` more than
    the reverse.
    """
    order = ranked(judged)
    if len(order) < 2 or not tied(judged[order[0]], judged[order[1]]):
        return Ranking(tuple(order))
    first, second = order[0], order[1]
    forward = follow_percent(data, first, second, first_sample, starts)
    backward = follow_percent(data, second, first, first_sample, starts)
    if backward >= FOLLOW_MIN_PERCENT and backward - forward >= FOLLOW_MARGIN_POINTS:
        order[0], order[1] = second, first
        forward, backward = backward, forward
    return Ranking(tuple(order), (order[0], order[1]), (forward, backward))


def follow_percent(
    data: DataSet,
    leader: str,
    follower: str,
    first_sample: int = 0,
    starts: Sequence[int] = ONE,
) -> float:
    """Share of ``follower``'s changes (RMS) that one or two lags of ``leader`` reproduce, held out.

    The candidate score of :func:`compd.model.lagscore.fit_candidate` with
    ``follower`` in place of the residue; 0 (cannot tell) on a record too
    short to diagnose. Several experiments (``starts``): the mean over them,
    each judged alone, weighted by its samples.
    """
    if len(starts) > 1:
        parts = spans(len(data), starts)
        shares = [
            _follow_percent(data.column(leader)[p], data.column(follower)[p], data.sample_time_s)
            for p in parts
        ]
        return float(np.average(shares, weights=[p.stop - p.start for p in parts]))
    return _follow_percent(
        data.column(leader), data.column(follower), data.sample_time_s, first_sample
    )


def _follow_percent(
    leader: np.ndarray, follower: np.ndarray, sample_time_s: float, first_sample: int = 0
) -> float:
    x = leader - leader[0]
    y = follower - follower[0]
    spread = float(np.std(x[first_sample:]))
    too_short = len(y) - first_sample < MIN_DIAGNOSED_SAMPLES
    if too_short or spread == 0.0 or float(np.std(y[first_sample:])) == 0.0:
        return 0.0
    taus = time_constant_bank(sample_time_s, (len(y) - first_sample) * sample_time_s)
    with threadpool_limits(limits=1, user_api="blas"):
        fit = fit_candidate(
            y - np.mean(y[first_sample:]),
            x / spread,
            taus,
            sample_time_s,
            folds=diagnosis_blocks(len(y) - first_sample),
            pair_margin_percent=2.0,
            first_sample=first_sample,
        )
    return float(fit.explained_percent)


def _resolved(path: str, folder: Path | None = None) -> str:
    try:
        return str(resolve_path(path, folder or Path()).resolve())
    except OSError:  # an unreadable path is compared as written
        return path


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(values)))) if values.size else float("nan")


def judge_signals(
    evaluation: Evaluation,
    output: str,
    measured_column: str,
    signals: Sequence[str],
    *,
    first_sample: int = 0,
) -> dict[str, HeldOut]:
    """:func:`judge_signal` for each of ``signals`` on ``evaluation``'s record (the same folds)."""
    data = evaluation.data
    folds = folds_of(data, operating_signal(data, None, None), first_sample, evaluation.starts)
    measured = data.column(measured_column)
    out = {}
    for signal in signals:
        prior = same_record_extensions(evaluation.model_file, output, data, signal)
        predicted = without_prior(evaluation, output, prior)
        out[signal], _ = judge_signal(
            data,
            measured,
            predicted,
            signal,
            prior=prior,
            first_sample=first_sample,
            folds=folds,
            starts=evaluation.starts,
        )
    return out


def held_out_json(held: HeldOut) -> dict[str, object]:
    """A judgement as ``extend --json`` and ``diagnose --json`` print it."""

    def clean(value: float) -> float | None:
        return float(value) if np.isfinite(value) else None

    return {
        "folds": held.folds,
        "fit_percent_before": clean(held.before),
        "fit_percent_after": clean(held.after),
        "rms_before_um": clean(held.rms_before_um),
        "rms_after_um": clean(held.rms_after_um),
        "error_removed_percent": clean(held.error_removed_percent),
        "folds_improved": held.folds_improved,
        "n_folds": held.n_folds,
        "fold_rms_before_um": [clean(v) for v in held.fold_rms_before_um],
        "fold_rms_after_um": [clean(v) for v in held.fold_rms_after_um],
        "accepted": held.accepted,
    }
