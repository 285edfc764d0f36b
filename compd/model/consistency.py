"""How each model input follows the other logged signals: a check on every reading, and its stand-in.

The temperatures of one machine move together, and the spindle's follow its
speed: on the calibration record each input is predicted from the *other*
signals. A reading far from its prediction is wrong (a plausible value of
45 degC where the others say 30 passes every range and rate check), and while
an input is wrong its prediction stands in for it (a virtual sensor), so the
model keeps compensating.

The prediction is linear in a feature vector: per signal its value and its
first-order low-passes at :data:`TAUS_S` (the structure answers heat with
lags), and for a spindle speed also ``(|n| / 1000 rpm) ** 1.5`` with its
low-passes (bearing friction heat grows faster than the speed). The features
are taken as jointly Gaussian on the calibration (their mean and a
ridge-regularised covariance), so the prediction of input ``i`` from *any*
subset ``K`` of the other signals is the conditional mean::

    x_i | z_K  =  mu_i + S_iK S_KK^-1 (z_K - mu_K)

One fit serves every combination of failed or unavailable predictors, and a
predictor outside what the calibration saw (25 % of its span beyond it; heavy
cutting at 10 kW after a calibration at 0.5 kW) is left out rather than
extrapolated. The spread that matters is how far the residue drifts from
where it was (a slow bias persists on a programme the calibration did not
run; the daemon takes it out): the RMS of its change over an hour, judged
honestly, fitted on one half of the calibration and judged on the other and
the other way round (:attr:`ConsistencyModel.sigma`).

Pure numpy; the daemon steps :class:`ConsistencyCheck` once a tick.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

#: Low-pass time constants of every signal's lag features (s): the default lag bank's
#: (:mod:`compd.model.lagbank`), minutes to hours, as the structure answers heat.
#: Written out, not imported: the daemon loads this module, and the lag bank needs scipy.
TAUS_S: tuple[float, ...] = (300.0, 1200.0, 3600.0, 10800.0)
#: The exponent of a spindle speed's heat feature, ``(|n| / 1000 rpm) ** HEAT_EXPONENT``.
HEAT_EXPONENT = 1.5
#: The residue's spread is judged as its change over this long (s): the daemon compares a
#: reading with its prediction shifted by the residue it had before (a bias that persists for
#: hours on a programme the calibration did not run), and a stand-in lasts about this long.
DRIFT_HORIZON_S = 3600.0
#: Ridge on the covariance, relative to each feature's variance.
RIDGE = 1e-3
#: A predictor this far (in its calibration span) beyond the calibration's range is left out.
RANGE_MARGIN = 0.25
#: A prediction is usable while it explains at least 80 % of the input's calibration variance (in
#: sample: a day's calibration lets a speed's hour-long low-passes "explain" two thirds of
#: the shop air by chance).
MIN_EXPLAINED = 0.8


def speed_feature(name: str) -> bool:
    """Whether ``name`` is a speed (``*_rpm``), which gets a heat feature."""
    return name.endswith("_rpm")


@dataclass(frozen=True)
class ConsistencyModel:
    """Each checked input as a linear function of the other signals' features, from the calibration."""

    #: The logged signals the features are built from, in feature order.
    signals: tuple[str, ...]
    #: The model inputs that are checked and can be stood in for (a subset of ``signals``).
    checked: tuple[str, ...]
    taus_s: tuple[float, ...]
    #: The speeds with a heat feature.
    heated: tuple[str, ...]
    #: Mean and covariance (ridge included) of the features on the calibration.
    mean: np.ndarray
    cov: np.ndarray
    #: Each feature's range on the calibration.
    low: np.ndarray
    high: np.ndarray
    #: Per checked input: the held-out RMS of its residue's change over :data:`DRIFT_HORIZON_S`
    #: (its unit) when predicted from all others.
    sigma: tuple[float, ...]
    #: Per checked input: the largest rate it moved at on the calibration (its unit per s).
    max_rate_per_s: tuple[float, ...]

    def groups(self) -> list[list[int]]:
        """Per signal, the indices of its features."""
        out, k = [], 0
        per = 1 + len(self.taus_s)
        for name in self.signals:
            n = per * (2 if name in self.heated else 1)
            out.append(list(range(k, k + n)))
            k += n
        return out


def feature_rows(
    columns: Mapping[str, np.ndarray],
    signals: Sequence[str],
    heated: Sequence[str],
    taus_s: Sequence[float],
    sample_time_s: float,
    starts: Sequence[int] = (0,),
) -> np.ndarray:
    """The feature matrix (samples x features) of a record; each low-pass starts at rest per experiment."""
    cols = []
    bounds = [*starts, len(next(iter(columns.values())))]
    for name in signals:
        x = np.asarray(columns[name], dtype=float)
        bases = [x] + ([_heat(x)] if name in heated else [])
        for base in bases:
            cols.append(base)
            for tau in taus_s:
                a = math.exp(-sample_time_s / tau)
                y = np.empty_like(base)
                for lo, hi in itertools.pairwise(bounds):
                    y[lo:hi] = _lowpass(base[lo:hi], a)
                cols.append(y)
    return np.column_stack(cols)


def fit_consistency(
    columns: Mapping[str, np.ndarray],
    checked: Sequence[str],
    sample_time_s: float,
    *,
    starts: Sequence[int] = (0,),
    taus_s: Sequence[float] = TAUS_S,
) -> ConsistencyModel | None:
    """The consistency model of ``checked`` from every column of ``columns`` (None: nothing to predict from).

    ``columns`` are the logged signals (not times or displacements); a column
    that does not move on the calibration carries nothing and is left out.
    """
    signals = [n for n, x in columns.items() if np.ptp(np.asarray(x, dtype=float)) > 0]
    checked = [c for c in checked if c in signals]
    if len(signals) < 2 or not checked:
        return None
    heated = tuple(n for n in signals if speed_feature(n))
    taus = tuple(float(t) for t in taus_s)
    features = feature_rows(columns, signals, heated, taus, sample_time_s, starts)
    mean, cov = _moments(features)
    half = len(features) // 2
    lag = max(1, round(DRIFT_HORIZON_S / sample_time_s))
    halves = [(slice(0, half), slice(half, None)), (slice(half, None), slice(0, half))]
    partial = ConsistencyModel(
        tuple(signals), tuple(checked), taus, heated, mean, cov,
        features.min(axis=0), features.max(axis=0), (), (),
    )  # fmt: skip
    groups = partial.groups()
    sigma, rates = [], []
    for name in checked:
        i = signals.index(name)
        others = [j for j in range(len(signals)) if j != i]
        squares, n = 0.0, 0
        for fit_part, judge_part in halves:
            m, c = _moments(features[fit_part])
            w, _ = _conditional(c, groups[i][0], [f for j in others for f in groups[j]])
            rest = [f for j in others for f in groups[j]]
            pred = m[groups[i][0]] + (features[judge_part][:, rest] - m[rest]) @ w
            residue = features[judge_part][:, groups[i][0]] - pred
            drift = (
                residue[lag:] - residue[:-lag] if len(residue) > lag else residue - residue.mean()
            )
            squares += float(drift @ drift)
            n += len(drift)
        sigma.append(math.sqrt(squares / max(n, 1)))
        x = np.asarray(columns[name], dtype=float)
        steps = np.abs(np.diff(x))
        rates.append(float(steps.max()) / sample_time_s if len(steps) else 0.0)
    return ConsistencyModel(
        tuple(signals), tuple(checked), taus, heated, mean, cov,
        features.min(axis=0), features.max(axis=0), tuple(sigma), tuple(rates),
    )  # fmt: skip


@dataclass(frozen=True)
class Prediction:
    """An input's prediction from the others this tick, or why there is none."""

    value: float
    #: The expected spread of the residue (its unit): the held-out sigma, widened as predictors drop out.
    sigma: float
    #: The signals it was predicted from.
    used: tuple[str, ...] = ()


@dataclass
class ConsistencyCheck:
    """The running prediction of every checked input: low-pass states, one step per tick."""

    model: ConsistencyModel
    period_s: float
    #: Signals the daemon reads; the others are left out of every prediction.
    available: frozenset[str]

    def __post_init__(self) -> None:
        model = self.model
        self._groups = model.groups()
        self._starts = np.array([g[0] for g in self._groups])
        per = 1 + len(model.taus_s)
        #: Per base (a signal's value, or a speed's heat), its signal and its feature position.
        self._base_signal = [
            j for j, n in enumerate(model.signals) for _ in range(1 + (n in model.heated))
        ]
        self._heat = np.array([
            b > 0 for j, n in enumerate(model.signals) for b in range(1 + (n in model.heated))
        ])  # fmt: skip
        self._base_at = np.arange(len(self._base_signal)) * per
        self._lows_at = self._base_at[:, None] + np.arange(1, per)[None, :]
        alpha = np.array([math.exp(-self.period_s / tau) for tau in model.taus_s])
        self._alpha = alpha[None, :]
        # Every feature against the range its base (a value, a heat) had on the calibration: a
        # low-pass never leaves its input's range, so this admits a warm start and refuses a
        # low-pass still full of a heat the calibration never saw (hours of 10 kW cutting).
        base_of = np.repeat(self._base_at, self._lows_at.shape[1] + 1)
        low, high = model.low[base_of], model.high[base_of]
        margin = RANGE_MARGIN * (high - low)
        self._low, self._high = low - margin, high + margin
        self._missing = np.array([n not in self.available for n in model.signals])
        self._state: np.ndarray | None = None
        self._cache: dict[tuple[int, frozenset[int]], tuple[np.ndarray, float, np.ndarray]] = {}
        self._all: dict[bytes, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self._checked = {name: model.signals.index(name) for name in model.checked}
        self._variance = {
            i: float(model.cov[self._starts[i], self._starts[i]]) for i in self._checked.values()
        }
        everyone = frozenset(range(len(model.signals)))
        self._full = {i: self._solve(i, everyone - {i})[1] for i in self._variance}
        self._checked_at = np.array([self._starts[self._checked[n]] for n in model.checked])

    @property
    def state(self) -> np.ndarray | None:
        """The features of the values used last tick (the low-passes' state; None before the first)."""
        return self._state

    @property
    def started(self) -> bool:
        return self._state is not None

    def features(self, values: Mapping[str, float]) -> np.ndarray:
        """This tick's feature vector, the low-passes advanced with ``values`` (NaN: held as they were)."""
        raw = np.array([values.get(n, math.nan) for n in self.model.signals], dtype=float)
        base = raw[self._base_signal]
        base[self._heat] = _heat(base[self._heat])
        z = np.empty(len(self.model.mean))
        z[self._base_at] = base
        if self._state is None:
            lows = np.repeat(base[:, None], self._lows_at.shape[1], axis=1)
        else:
            previous = self._state[self._lows_at]
            lows = self._alpha * previous + (1 - self._alpha) * base[:, None]
            lows = np.where(np.isfinite(base)[:, None], lows, previous)
            lows = np.where(np.isfinite(previous), lows, base[:, None])
        z[self._lows_at] = lows
        return z

    def advance(self, z: np.ndarray) -> None:
        """Keep ``z`` (the features of the values used this tick) as the low-passes' state."""
        self._state = z

    def shift(self, signal: str, delta: float) -> None:
        """Move ``signal``'s low-passes by ``delta`` (its unit), as if it had always read that much
        more: a sensor vouched for at a new offset starts without a transient."""
        if self._state is None:
            return
        start = self._starts[self.model.signals.index(signal)]
        self._state[start + 1 : start + 1 + len(self.model.taus_s)] += delta

    def usable(self, z: np.ndarray, unusable: set[str]) -> np.ndarray:
        """Per signal: whether it may predict the others this tick (read, finite, within its calibration)."""
        inside = np.isfinite(z) & (z >= self._low) & (z <= self._high)
        ok: np.ndarray = np.logical_and.reduceat(inside, self._starts) & ~self._missing
        signals = self.model.signals
        for name in unusable:
            if name in signals:  # a signal the consistency model does not read predicts nothing
                ok[signals.index(name)] = False
        return ok

    def predict(self, z: np.ndarray, name: str, ok: np.ndarray) -> Prediction | None:
        """``name`` predicted from the signals ``ok`` marks (:meth:`usable`); None when they explain too little."""
        i = self._checked[name]
        keep = frozenset(int(j) for j in np.flatnonzero(ok) if j != i)
        if not keep:
            return None
        w, variance, rest = self._solve(i, keep)
        if variance > (1 - MIN_EXPLAINED) * self._variance[i]:
            return None
        at = self._starts[i]
        model = self.model
        value = float(model.mean[at] + (z[rest] - model.mean[rest]) @ w)
        sigma = model.sigma[model.checked.index(name)] * math.sqrt(variance / self._full[i])
        return Prediction(value, sigma, tuple(model.signals[j] for j in sorted(keep)))

    def predict_all(self, z: np.ndarray, ok: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Every checked input predicted at once: values and sigmas in :attr:`ConsistencyModel.checked`
        order, NaN where the others explain too little (as :meth:`predict`, one product per tick)."""
        key = ok.tobytes()
        if key not in self._all:
            if len(self._all) > 256:  # a bound: the combinations seen are few
                self._all.clear()
            self._all[key] = self._stack(ok)
        weights, offsets, sigmas = self._all[key]
        # A feature of a signal left out has weight 0, and may be NaN (a sensor that read NaN).
        return offsets + weights @ np.where(np.isfinite(z), z, 0.0), sigmas

    def residues(self, z: np.ndarray, ok: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Every checked input's residue, its own value in ``z`` minus its prediction from the
        signals ``ok`` marks, and the prediction's sigma (NaN: no prediction).

        Linear in ``z``: the residue of an average of feature vectors is the average of their
        residues, under any set of predictors. So a level kept as averaged features (not as
        averaged residues) carries over exactly when a predictor drops out or returns.
        """
        predicted, sigmas = self.predict_all(z, ok)
        return z[self._checked_at] - predicted, sigmas

    def _stack(self, ok: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        model = self.model
        weights = np.zeros((len(model.checked), len(model.mean)))
        offsets = np.full(len(model.checked), np.nan)
        sigmas = np.full(len(model.checked), np.nan)
        for row, name in enumerate(model.checked):
            i = self._checked[name]
            keep = frozenset(int(j) for j in np.flatnonzero(ok) if j != i)
            if not keep:
                continue
            w, variance, rest = self._solve(i, keep)
            if variance > (1 - MIN_EXPLAINED) * self._variance[i]:
                continue
            weights[row, rest] = w
            at = self._starts[i]
            offsets[row] = model.mean[at] - model.mean[rest] @ w
            sigmas[row] = model.sigma[row] * math.sqrt(variance / self._full[i])
        return weights, offsets, sigmas

    def _solve(self, i: int, keep: frozenset[int]) -> tuple[np.ndarray, float, np.ndarray]:
        key = (i, keep)
        if key not in self._cache:
            rest = np.array([f for j in sorted(keep) for f in self._groups[j]])
            w, variance = _conditional(self.model.cov, int(self._starts[i]), list(rest))
            self._cache[key] = (w, variance, rest)
        return self._cache[key]


def _conditional(cov: np.ndarray, target: int, rest: list[int]) -> tuple[np.ndarray, float]:
    """Weights of ``rest`` predicting ``target`` and the conditional variance."""
    s_rr = cov[np.ix_(rest, rest)]
    s_tr = cov[target, rest]
    w = np.linalg.solve(s_rr, s_tr)
    return w, max(float(cov[target, target] - s_tr @ w), 1e-12)


def _moments(features: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    mean = features.mean(axis=0)
    cov = np.atleast_2d(np.cov(features, rowvar=False))
    scale = np.diag(cov).copy()
    cov = cov + np.diag(RIDGE * scale + 1e-12 * max(float(scale.max()), 1.0))
    return mean, cov


def _heat(x: np.ndarray) -> np.ndarray:
    return np.abs(x / 1000.0) ** HEAT_EXPONENT


def _lowpass(x: np.ndarray, a: float) -> np.ndarray:
    """``y[k] = a y[k-1] + (1 - a) x[k]``, starting at rest (``y[-1] = x[0]``)."""
    if len(x) == 0:
        return x.copy()
    from scipy.signal import lfilter

    return np.asarray(lfilter([1.0 - a], [1.0, -a], x, zi=[a * x[0]])[0])
