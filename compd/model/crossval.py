"""Cross-validation that respects time: leave one operating cycle out.

A thermal model is judged on how it runs through conditions it was not fitted
on. Random sample splits leak (neighbouring samples 15 s apart are the same
thermal state), and "the last third" of a calibration is usually its hottest
or fastest part: an extrapolation. So the folds here are whole operating
cycles: a cycle starts where the machine starts working (a rising edge of the
spindle speed, or whatever operating signal is given) and lasts until the
next one. Consecutive cycles are merged so there are at most ``max_folds``
folds; a record with fewer than ``min_folds`` cycles falls back to contiguous
blocks of equal length.

Every model is run through the *whole* record (inputs referenced to the
record's start, state carried through every cycle); only which samples enter
the fit changes from fold to fold. The score is the fit % (Horejs 2015 eq. 2)
of all held-out predictions pooled: a fold that the model misses by a lot
counts by its size, not averaged away.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from compd.errors import ModelError
from compd.model.experiments import spans
from compd.model.metrics import fit_percent

#: A fold that holds fewer samples than this is merged into its neighbour.
MIN_FOLD_SAMPLES = 20

#: Fits the model on the samples where the mask is True and returns its prediction
#: over the whole record (run from the record's start).
FitPredict = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class Folds:
    """A fold label per sample (0..n_folds-1) and how the folds were made."""

    labels: np.ndarray
    kind: str  # "cycles of SIGNAL" or "contiguous blocks"

    @property
    def n_folds(self) -> int:
        return int(self.labels.max()) + 1

    def describe(self) -> str:
        return f"leave one of {self.n_folds} {self.kind} out"


def blocked_folds(n_samples: int, n_folds: int = 4) -> Folds:
    """``n_folds`` contiguous blocks of (nearly) equal length; fewer (at least 2) on a short record.

    A short record (70 samples of 5 min: a 6 h warm-up) is still a record a
    user fits: it is cut into as many blocks of :data:`MIN_FOLD_SAMPLES` as it holds.
    """
    n_folds = max(2, min(n_folds, n_samples // MIN_FOLD_SAMPLES))
    if n_samples < n_folds * MIN_FOLD_SAMPLES:
        raise ModelError(
            f"{n_samples} samples are too few to cross-validate in {n_folds} blocks "
            f"(at least {MIN_FOLD_SAMPLES} per block)"
        )
    labels = (np.arange(n_samples) * n_folds) // n_samples
    return Folds(labels.astype(int), "contiguous blocks")


def cycle_folds(
    operating: np.ndarray,
    *,
    name: str = "the operating signal",
    max_folds: int = 6,
    min_folds: int = 3,
    blocks: int = 4,
) -> Folds:
    """Folds of whole operating cycles, each from one start of work (``operating`` rises above 0) to the next.

    The samples before the first start belong to the first cycle. With more
    cycles than ``max_folds``, consecutive cycles are merged into folds of
    nearly equal sample counts; with fewer than ``min_folds``, contiguous blocks.
    """
    on = np.asarray(operating, dtype=float) > 0.0
    n = on.size
    starts = np.flatnonzero(on[1:] & ~on[:-1]) + 1
    # The first cycle runs from the record's start (any idle lead-in) to the second start.
    bounds = [0, *[int(s) for s in starts[1:]], n]
    # Merge cycles that are too short to judge into the previous one.
    merged = [bounds[0]]
    for b in bounds[1:-1]:
        if b - merged[-1] >= MIN_FOLD_SAMPLES and n - b >= MIN_FOLD_SAMPLES:
            merged.append(b)
    merged.append(n)
    n_cycles = len(merged) - 1
    if n_cycles < min_folds:
        return blocked_folds(n, blocks)
    cycle_of = np.searchsorted(np.asarray(merged[1:-1]), np.arange(n), side="right")
    if n_cycles > max_folds:
        # Group whole cycles by where their start falls in equal shares of the record.
        cycle_start = np.asarray(merged[:-1])
        group = np.minimum((cycle_start * max_folds) // n, max_folds - 1)
        _, group = np.unique(group, return_inverse=True)
        labels = group[cycle_of]
    else:
        labels = cycle_of
    return Folds(labels.astype(int), f"operating cycles of {name}")


def experiment_folds(n_samples: int, starts: Sequence[int], max_folds: int = 6) -> Folds:
    """Leave one experiment out: each stacked experiment is a fold (neighbours merged beyond ``max_folds``).

    Experiments are the natural folds of several records: a model that holds
    on a day, a machine or a programme it was not fitted on.
    """
    parts = spans(n_samples, starts)
    experiment = np.repeat(np.arange(len(parts)), [p.stop - p.start for p in parts])
    labels = (experiment * min(max_folds, len(parts))) // len(parts)
    return Folds(labels.astype(int), "experiments (files)")


def cross_validated_prediction(
    fit_predict: FitPredict, folds: Folds, scored: np.ndarray | None = None
) -> np.ndarray:
    """Each scored sample predicted by the model fitted on every other fold's scored samples.

    Samples outside ``scored`` (default: all) are neither fitted nor predicted (NaN).
    """
    n = folds.labels.size
    scored = np.ones(n, dtype=bool) if scored is None else np.asarray(scored, dtype=bool)
    prediction = np.full(n, np.nan)
    for fold in range(folds.n_folds):
        held = scored & (folds.labels == fold)
        train = scored & (folds.labels != fold)
        if not held.any() or not train.any():
            continue
        prediction[held] = fit_predict(train)[held]
    return prediction


def pooled_fit_percent(measured: np.ndarray, predicted: np.ndarray) -> float:
    """Fit % (Horejs 2015 eq. 2) over the samples that have a held-out prediction."""
    held = np.isfinite(predicted)
    if held.sum() < 2:
        raise ModelError("no held-out predictions to score")
    return float(fit_percent(measured[held], predicted[held]))
