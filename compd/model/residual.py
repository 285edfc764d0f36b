"""Residual model for door openings (Swiss-lathe paper): smoothed door features and a random forest as arrays.

Swiss-lathe paper stacks a random-forest regression on the residue of the TF model:
``y(k) = sum_i TF_i(...) + RF(features(k))``. The forest's only input is the
door status smoothed by a logistic (Swiss-lathe paper eq. 9). Eq. 9 as printed,
``y_smoothed = y_t / (1 + exp(-k (t0 - t)))`` with ``k = +-1`` per change,
is a logistic transition centred on the change time ``t0``; centred there it
would need the future. compd uses the causal half of that logistic, starting
at the instant of the change and reaching the new state with time constant
``tau`` (s)::

    f_tau(t) = s0 + (d - s0) * (2 sigma((t - t0) / tau) - 1)
             = s0 + (d - s0) * tanh((t - t0) / (2 tau))

where ``d`` in {0, 1} is the door state since the last change at ``t0`` and
``s0`` the feature's value at ``t0`` (so a change back before the transition
ends starts from where it got to, without a jump). Several ``tau`` give the
forest fast and slow views of the air exchange (a door open for 3 min and
one open for 10 min differ in the slow feature only); a last feature is the
time since the last change in s, capped at ``20 * max(tau)``.

The feature state per residual is ``[d, elapsed_s, s0_1 .. s0_m]``: the same
recursion runs per tick (:meth:`DoorFeatures.step`) and over a record
(:meth:`DoorFeatures.record`, vectorised per door segment), to rounding.

The forest is plain arrays (no pickle): all trees' nodes in one flat table
whose leaves point to themselves, so ``depth`` rounds of
``node = where(x[feature[node]] <= threshold[node], left[node], right[node])``
reach every tree's leaf at once (per tick); over a record the same steps
run one tree at a time over all samples. The features are rounded to float32 before
the comparison because scikit-learn's trees compare float32 inputs with
float64 thresholds; with that the prediction equals ``predict`` exactly.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np

from compd.errors import ModelError

#: Door feature time constants (s): about the shortest opening, a long one, and the cool-down.
DEFAULT_TIME_CONSTANTS_S = (120.0, 600.0, 1800.0)


@dataclass(frozen=True)
class DoorFeatures:
    """The causal logistic smoothing of Swiss-lathe paper eq. 9 at time constants ``time_constants_s``.

    ``signal`` is open while ``> threshold``. Features, in order: one smoothed
    door state per time constant (0 shut .. 1 open), then the seconds since
    the last change (capped at ``20 * max(tau)``).
    """

    signal: str
    time_constants_s: tuple[float, ...] = DEFAULT_TIME_CONSTANTS_S
    threshold: float = 0.5

    def __post_init__(self) -> None:
        taus = np.asarray(self.time_constants_s, dtype=float)
        if taus.size == 0 or not np.all(np.isfinite(taus)) or np.any(taus <= 0):
            raise ModelError(
                f"door feature time constants must be > 0 s, got {list(self.time_constants_s)}"
            )
        if not np.isfinite(self.threshold):
            raise ModelError(f"door threshold must be finite, got {self.threshold}")

    @property
    def n_features(self) -> int:
        return len(self.time_constants_s) + 1

    @property
    def state_size(self) -> int:
        """``[d, elapsed_s, s0 per time constant]``."""
        return len(self.time_constants_s) + 2

    @property
    def cap_s(self) -> float:
        return 20.0 * max(self.time_constants_s)

    def feature_names(self) -> tuple[str, ...]:
        smoothed = tuple(f"{self.signal}_smoothed_{tau:g}s" for tau in self.time_constants_s)
        return (*smoothed, f"{self.signal}_since_change_s")

    def initial_state(self, value: float) -> np.ndarray:
        """The state of a door held at ``value`` for a long time (all features settled)."""
        d = float(value > self.threshold)
        return np.array([d, self.cap_s, *([d] * len(self.time_constants_s))])

    def step(self, state: np.ndarray, value: float, dt_s: float) -> np.ndarray:
        """Advance ``state`` (in place) by one sample of ``dt_s`` and return the features."""
        taus = np.asarray(self.time_constants_s)
        d = float(value > self.threshold)
        elapsed = min(state[1] + dt_s, self.cap_s)
        s0 = state[2:]
        if d != state[0]:
            s0 += (state[0] - s0) * np.tanh(elapsed / (2.0 * taus))
            elapsed = 0.0
            state[0] = d
        state[1] = elapsed
        features = np.empty(self.n_features)
        features[:-1] = s0 + (d - s0) * np.tanh(elapsed / (2.0 * taus))
        features[-1] = elapsed
        return features

    def record(
        self, values: np.ndarray, dt_s: float, state: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Features (N, n_features) over ``values`` from ``state``, and the state after the last sample."""
        taus = np.asarray(self.time_constants_s)
        door = (np.asarray(values, dtype=float) > self.threshold).astype(float)
        n = door.size
        features = np.empty((n, self.n_features))
        d, elapsed, s0 = float(state[0]), float(state[1]), np.array(state[2:], dtype=float)
        previous = np.concatenate([[d], door[:-1]])
        starts = np.flatnonzero(door != previous)
        if n and (starts.size == 0 or starts[0] != 0):
            starts = np.concatenate([[0], starts])
        bounds = np.append(starts, n)
        for a, b in itertools.pairwise(bounds):
            first = min(elapsed + dt_s, self.cap_s)
            if door[a] != d:
                s0 = s0 + (d - s0) * np.tanh(first / (2.0 * taus))
                first, d = 0.0, float(door[a])
            seg = np.minimum(first + dt_s * np.arange(b - a), self.cap_s)
            features[a:b, :-1] = s0 + (d - s0) * np.tanh(seg[:, None] / (2.0 * taus))
            features[a:b, -1] = seg
            elapsed = float(seg[-1])
        return features, np.array([d, elapsed, *s0])


@dataclass(frozen=True, eq=False)
class Forest:
    """Regression trees as one flat node table; the prediction is the mean of the trees' leaves.

    ``roots`` (T,) index each tree's root; per node ``left``/``right`` the
    children (a leaf points to itself), ``feature`` the feature index tested
    (0 at leaves), ``threshold`` the split (go left when ``x <= threshold``),
    ``value`` the tree's prediction there (um).
    """

    roots: np.ndarray
    left: np.ndarray
    right: np.ndarray
    feature: np.ndarray
    threshold: np.ndarray
    value: np.ndarray
    n_features: int
    depth: int = field(init=False)

    def __post_init__(self) -> None:
        n = self.left.shape[0]
        arrays = (self.left, self.right, self.feature, self.threshold, self.value)
        if self.roots.ndim != 1 or self.roots.size == 0 or any(a.shape != (n,) for a in arrays):
            raise ModelError("forest arrays must be 1-D, one entry per node, with >= 1 tree")
        for name in ("roots", "left", "right"):
            index = getattr(self, name)
            if index.size and (index.min() < 0 or index.max() >= n):
                raise ModelError(f"forest {name} index out of range 0..{n - 1}")
        if self.feature.min() < 0 or self.feature.max() >= self.n_features:
            raise ModelError(f"forest feature index out of range 0..{self.n_features - 1}")
        if not (np.all(np.isfinite(self.threshold)) and np.all(np.isfinite(self.value))):
            raise ModelError("forest thresholds and values must be finite")
        nodes = np.arange(n)
        leaf = (self.left == nodes) & (self.right == nodes)
        # Children after their parent (scikit-learn's pre-order) rules out cycles.
        if np.any(~leaf & ((self.left <= nodes) | (self.right <= nodes))):
            raise ModelError("forest nodes must list children after their parent")
        depth, frontier = 0, self.roots
        while not leaf[frontier].all():
            inner = frontier[~leaf[frontier]]
            frontier = np.concatenate([self.left[inner], self.right[inner]])
            depth += 1
        object.__setattr__(self, "depth", depth)

    @property
    def n_trees(self) -> int:
        return int(self.roots.size)

    @property
    def n_nodes(self) -> int:
        return int(self.left.size)

    def predict_one(self, x: np.ndarray) -> float:
        """One sample's prediction (um): ``depth`` vectorised steps over all trees."""
        x = np.asarray(x, dtype=np.float32).astype(float)
        node = self.roots
        for _ in range(self.depth):
            node = np.where(
                x[self.feature[node]] <= self.threshold[node], self.left[node], self.right[node]
            )
        return float(self.value[node].mean())

    def predict(self, x: np.ndarray) -> np.ndarray:
        """Predictions (N,) in um for features ``x`` (N, n_features).

        One tree at a time over all samples: each tree's nodes stay in cache,
        which is about twice as fast as all trees at once over blocks of samples.
        """
        x = np.asarray(x, dtype=np.float32).astype(float)
        if x.ndim != 2 or x.shape[1] != self.n_features:
            raise ModelError(f"forest needs (N, {self.n_features}) features, got {x.shape}")
        n = x.shape[0]
        by_feature = np.ascontiguousarray(x.T).ravel()  # feature f of sample i at f * n + i
        samples = np.arange(n)
        total = np.zeros(n)
        for root in self.roots:
            node = np.full(n, root)
            for _ in range(self.depth):
                go_left = by_feature[self.feature[node] * n + samples] <= self.threshold[node]
                node = np.where(go_left, self.left[node], self.right[node])
            total += self.value[node]
        out: np.ndarray = total / self.n_trees
        return out


@dataclass(frozen=True, eq=False)
class ResidualModel:
    """Swiss-lathe paper's stacked term for one output: ``forest(door features(k))`` in um, added to the TF sum."""

    features: DoorFeatures
    forest: Forest

    def __post_init__(self) -> None:
        if self.forest.n_features != self.features.n_features:
            raise ModelError(
                f"forest reads {self.forest.n_features} features but the door features give "
                f"{self.features.n_features}"
            )

    @property
    def signal(self) -> str:
        return self.features.signal

    def simulate(
        self, values: np.ndarray, dt_s: float, state: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """The residual (N,) in um over a record of the door signal, and the final feature state."""
        features, final = self.features.record(values, dt_s, state)
        return self.forest.predict(features), final

    def step(self, state: np.ndarray, value: float, dt_s: float) -> float:
        """One tick: advance the feature state in place and return the residual in um."""
        return self.forest.predict_one(self.features.step(state, value, dt_s))
