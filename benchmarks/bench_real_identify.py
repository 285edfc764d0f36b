"""Identification on a real machine's record, judged by leave-one-cycle-out: methods side by side.

The record is ``tests/data/fl_thermal_train.csv`` (32.1 h at 15 s, 16
temperatures, 5 displacement channels, four 8 h heat/cool cycles at 1250,
2500, 3750 and 5000 rpm). Every method gets all 16 temperatures as changes
from the record's start. Folds are the four cycles; each held-out cycle is
predicted by the model fitted on the other three, run through the whole
record; the fit % (Horejs 2015 eq. 2) of the four held-out predictions pooled is
the figure. Per method and channel:

- ``calibration``: the fit on all the data it was fitted on (proves nothing);
- ``LOCO``: the held-out fit, with settings chosen by the same four folds
  (the definition in issue 12, where the baselines below come from);
- ``nested``: settings chosen inside each training set only (leave one of the
  other three cycles out), so the held-out cycle plays no part in any choice:
  the stricter figure.

Methods: ``mlr`` (the controllers' static regression), ``ridge-raw`` (the
issue's 30-line baseline: lags at 0, 5 min, 20 min, 1 h, 3 h on the raw
sensors, one ridge weight by LOCO), ``lagbank`` (compd's default: the same lags
on the sensors' principal directions, modes and weight by LOCO). Issue 12's
figures for comparison (LOCO): regression 17/14/73/73/27, ridge lag bank
59/60/78/78/62; target: the default beats mlr on every channel and 78 % on
ch3/ch4 (aim 85 %); a 16-input fit with its cross-validation < 10 s.

Run: ``PYTHONPATH=. python benchmarks/bench_real_identify.py`` from the repository root.
"""

from __future__ import annotations

import os

for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_name] = "1"

import sys  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from common import environment, verdict  # noqa: E402

from compd.model.crossval import (  # noqa: E402
    Folds,
    cross_validated_prediction,
    cycle_folds,
    pooled_fit_percent,
)
from compd.model.lagbank import (  # noqa: E402
    DEFAULT_RIDGE_WEIGHTS,
    DEFAULT_TIME_CONSTANTS_S,
    fit_lag_bank,
    lag_features,
    regression_cv,
)
from compd.model.metrics import fit_percent  # noqa: E402
from compd.toolkit.nestedselect import compare_candidates  # noqa: E402

RECORD = Path(__file__).resolve().parents[1] / "tests" / "data" / "fl_thermal_train.csv"
ISSUE_REGRESSION = (17, 14, 73, 73, 27)
ISSUE_RIDGE = (59, 60, 78, 78, 62)
FIT_MAX_S = 10.0


def _ridge_raw(y: np.ndarray, u: np.ndarray, folds: Folds, dt_s: float) -> tuple[float, float]:
    """The issue's baseline: ridge on standardised raw-sensor lags, the weight of the best LOCO."""
    x = lag_features(u, DEFAULT_TIME_CONSTANTS_S, dt_s)

    def fitter(weight: float) -> Callable[[np.ndarray], np.ndarray]:
        def fit_predict(train: np.ndarray) -> np.ndarray:
            scale = x[train].std(axis=0)
            z = x[train] / scale
            w = np.linalg.solve(z.T @ z + weight * train.sum() * np.eye(z.shape[1]), z.T @ y[train])
            return np.asarray((x / scale) @ w)

        return fit_predict

    scores = {
        w: pooled_fit_percent(y, cross_validated_prediction(fitter(w), folds))
        for w in DEFAULT_RIDGE_WEIGHTS
    }
    best = max(scores, key=scores.__getitem__)
    full = fitter(best)(np.ones(y.size, dtype=bool))
    return float(fit_percent(y, full)), scores[best]


def _mlr(y: np.ndarray, u: np.ndarray, folds: Folds) -> tuple[float, float]:
    gains, cv = regression_cv(y, u, folds)
    return float(fit_percent(y, u @ gains)), cv


def _pca_nested(y: np.ndarray, u: np.ndarray, folds: Folds, dt_s: float) -> float:
    """The principal-direction bank (issue 12's default) with its settings chosen on the other cycles only."""
    prediction = np.full(y.size, np.nan)
    for fold in range(folds.n_folds):
        held = folds.labels == fold
        inner = fit_lag_bank(y, u, sample_time_s=dt_s, folds=folds, fitted=~held)
        prediction[held] = inner.predicted_um[held]
    return pooled_fit_percent(y, prediction)


def _default(y: np.ndarray, u: np.ndarray, folds: Folds, dt_s: float) -> dict[str, object]:
    """The default ``compd fit`` (:func:`compare_candidates`): kept method, its printed figure, time.

    Also the whole default procedure (the kept method too) judged nested: each
    cycle predicted by what the default keeps on the other three, run through
    the record (``nested``), and the expected figure if each held-out cycle is
    judged as a new recording (``new_rec``, ``compare_candidates(new_recordings=True)``).
    """
    inputs = {f"T{i + 1}": u[:, i] for i in range(u.shape[1])}
    started = time.perf_counter()
    selection = compare_candidates(
        y, inputs, sample_time_s=dt_s, folds=folds, candidates=("lagbank", "mlr")
    )
    elapsed = time.perf_counter() - started
    new_rec = compare_candidates(
        y, inputs, sample_time_s=dt_s, folds=folds, candidates=("lagbank", "mlr"),
        new_recordings=True,
    )  # fmt: skip
    nested = np.full(y.size, np.nan)
    for fold in range(folds.n_folds):
        held = folds.labels == fold
        inner = compare_candidates(
            y, inputs, sample_time_s=dt_s, folds=folds, candidates=("lagbank", "mlr"),
            fitted=~held,
        )  # fmt: skip
        if inner.kept == "lagbank" and inner.lag_bank is not None:
            nested[held] = inner.lag_bank.predicted_um[held]
        else:
            nested[held] = (u @ np.linalg.lstsq(u[~held], y[~held], rcond=None)[0])[held]
    score = selection.score(selection.kept)
    new_score = new_rec.score(new_rec.kept)
    assert score is not None and new_score is not None
    return {
        "kept": selection.kept,
        "printed": score.expected_percent,
        "nested": pooled_fit_percent(y, nested),
        "new_rec": f"{new_score.expected_percent:.1f} {new_rec.kept}",
        "seconds": elapsed,
    }


def main() -> int:
    print(environment())
    data = pd.read_csv(RECORD)
    dt_s = float(np.median(np.diff(data["time_s"])))
    temperatures = data[[f"T{i}" for i in range(1, 17)]].to_numpy()
    u = temperatures - temperatures[0]
    folds = cycle_folds(data["spindle_speed_rpm"].to_numpy(), name="spindle_speed_rpm")
    print(f"{RECORD.name}: {len(data)} samples at {dt_s:g} s, 16 temperatures; {folds.describe()}")
    header = (
        f"{'channel':<8}{'mlr':>7}{'ridge-raw':>10}{'PCA LOCO':>9}{'PCA nested':>11}"
        f"{'kept':>9}{'printed':>9}{'nested':>8}{'as new recordings':>19}{'fit s':>7}"
    )
    print("fit % by leave-one-cycle-out")
    print(header)
    print("-" * len(header))
    ok = True
    slowest = 0.0
    for channel in range(1, 6):
        y = data[f"disp_ch{channel}_um"].to_numpy()
        _, mlr_cv = _mlr(y, u, folds)
        _, ridge_cv = _ridge_raw(y, u, folds, dt_s)
        pca = fit_lag_bank(y, u, sample_time_s=dt_s, folds=folds)
        pca_nested = _pca_nested(y, u, folds, dt_s)
        default = _default(y, u, folds, dt_s)
        slowest = max(slowest, float(default["seconds"]))  # type: ignore[arg-type]
        print(
            f"{'ch' + str(channel):<8}{mlr_cv:>7.1f}{ridge_cv:>10.1f}{pca.cv_fit_percent:>9.1f}"
            f"{pca_nested:>11.1f}{default['kept']!s:>9}{default['printed']:>9.1f}"
            f"{default['nested']:>8.1f}{default['new_rec']!s:>19}{default['seconds']:>7.2f}"
        )
        ok &= float(default["nested"]) >= mlr_cv - 0.1  # type: ignore[arg-type]
    fast = slowest < FIT_MAX_S
    print(
        "default not below mlr, nested, every channel: "
        f"{verdict(ok)}; slowest 16-input default fit with its nested cross-validation: "
        f"{slowest:.2f} s (target < {FIT_MAX_S:g} s): {verdict(fast)}"
    )
    return 0 if ok and fast else 1


if __name__ == "__main__":
    sys.exit(main())
