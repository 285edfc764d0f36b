"""Post-process update of sub-model gains from sparse measurements (Post-process 2024 eq. 6-9).

Post-process 2024 eq. 6 multiplies whole sub-models by gains ``g1, g2, ...``::

    y(k; g) = f(k) + sum_j g_j c_j(k)

where ``c_j`` (um) is the contribution of the sub-models sharing gain ``j``,
simulated once with gain 1, and ``f`` (um) the sum of the sub-models whose
gain stays fixed. The output is linear in ``g``, so the sum of squared
residues over any set of instants is a quadratic form,

    J(g) = ||r0 - C g||^2 = g' (C'C) g - 2 (C' r0)' g + r0' r0,  r0 = y_measured - f,

precomputed once as a Gram matrix: evaluating it costs ``G^2`` operations
whatever the record length, so a genetic-type global search (scipy's
``differential_evolution``, as Post-process 2024 uses a GA) over thousands of candidate
gain vectors takes milliseconds instead of thousands of re-simulations.

- :func:`update_gains`: eq. 8/9, the residue at the probe instants only,
  within bounds (default ``(0, 2)``, eq. 9).
- :func:`characteristic_bounds`: eq. 7, the best gains on each interval
  between changes of technological conditions of a continuously measured run;
  their range (with a margin) bounds later probe-only updates.

Post-process 2024 writes eq. 8 with absolute residues; the squared form used here has
the same minimiser for exact data and weighs large probe errors more, which
is what compensation is judged on (RMS, fit %).
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import differential_evolution

from compd.errors import ModelError

#: Post-process 2024 eq. 9: the default search interval of every gain.
DEFAULT_BOUNDS = (0.0, 2.0)
#: A gain whose contribution over an interval is below this fraction of the
#: largest one there is not determined by that interval (eq. 7 skips it).
EXCITATION_TOLERANCE = 0.01


@dataclass(frozen=True, eq=False)
class GainProblem:
    """``J(g) = ||r0 - C g||^2`` in Gram form: ``g' A g - 2 b' g + c`` (um^2)."""

    gram: np.ndarray  # (G, G) C'C
    cross: np.ndarray  # (G,) C' r0
    energy: float  # r0' r0
    n_rows: int
    rank: int

    @classmethod
    def of(
        cls,
        contributions_um: np.ndarray,
        measured_um: np.ndarray,
        fixed_um: np.ndarray | None = None,
    ) -> GainProblem:
        """From ``C`` (rows x gains, each gain's contribution at gain 1) and the measured rows."""
        c = np.atleast_2d(np.asarray(contributions_um, dtype=float))
        r0 = np.asarray(measured_um, dtype=float).ravel()
        if fixed_um is not None:
            r0 = r0 - np.asarray(fixed_um, dtype=float).ravel()
        if c.shape[0] != r0.size:
            raise ModelError(f"{c.shape[0]} rows of contributions but {r0.size} measured values")
        if not (np.all(np.isfinite(c)) and np.all(np.isfinite(r0))):
            raise ModelError("contributions and measurements must be finite")
        rank = int(np.linalg.matrix_rank(c)) if c.size else 0
        return cls(c.T @ c, c.T @ r0, float(r0 @ r0), int(r0.size), rank)

    @property
    def n_gains(self) -> int:
        return int(self.cross.size)

    def sum_squares(self, gains: np.ndarray) -> np.ndarray:
        """``J`` for gains of shape ``(G,)`` (a scalar array) or ``(G, S)`` (``S`` candidates)."""
        g = np.asarray(gains, dtype=float)
        quadratic = np.einsum("i...,ij,j...->...", g, self.gram, g)
        value: np.ndarray = np.maximum(quadratic - 2.0 * (self.cross @ g) + self.energy, 0.0)
        return value


@dataclass(frozen=True, eq=False)
class GainUpdate:
    """Gains found by :func:`update_gains` and the residue at the probes before and after (um)."""

    gains: np.ndarray  # (G,)
    bounds: np.ndarray  # (G, 2)
    rms_after_um: float
    rms_before_um: float  # at ``initial_gains``; NaN when they were not given
    n_rows: int
    rank: int
    at_bound: np.ndarray  # (G,) bool: the optimum sits on a bound (the bound is active)
    evaluations: int

    @property
    def well_determined(self) -> bool:
        """True when the probes determine every gain (full column rank)."""
        return self.rank == self.gains.size


def check_bounds(bounds: np.ndarray | Sequence[tuple[float, float]], n_gains: int) -> np.ndarray:
    """Bounds as a ``(G, 2)`` array of finite ``low < high``; a bad pair is named by index."""
    array = np.asarray(bounds, dtype=float).reshape(-1, 2) if len(bounds) else np.empty((0, 2))
    if array.shape != (n_gains, 2):
        raise ModelError(f"need {n_gains} (low, high) bounds, got {array.shape[0]}")
    for j, (low, high) in enumerate(array):
        if not (np.isfinite(low) and np.isfinite(high) and low < high):
            raise ModelError(
                f"bounds of gain {j} must be finite with low < high, got ({low}, {high})"
            )
    return array


def check_well_posed(n_rows: int, n_gains: int) -> None:
    """Refuse fewer measurements than gains: eq. 8 would have a continuum of optima."""
    if n_gains == 0:
        raise ModelError("there is no gain to update")
    if n_rows < n_gains:
        raise ModelError(
            f"{n_rows} probe value(s) cannot determine {n_gains} gains; probe at least "
            f"{n_gains} times (Post-process 2024 probes at every change of technological conditions), "
            "or update fewer gains"
        )


def _minimise(problem: GainProblem, bounds: np.ndarray, seed: int) -> tuple[np.ndarray, int]:
    def objective(gains: np.ndarray) -> np.ndarray:
        return problem.sum_squares(gains)

    # vectorized: the whole population in one call; polish: L-BFGS-B from the best
    # member, within the bounds, to land exactly on the quadratic's constrained optimum.
    result = differential_evolution(
        objective,
        bounds=[tuple(b) for b in bounds],
        seed=seed,
        polish=True,
        vectorized=True,
        updating="deferred",
        tol=1e-10,
        atol=0.0,
        maxiter=1000,
    )
    gains = np.clip(np.asarray(result.x, dtype=float), bounds[:, 0], bounds[:, 1])
    return gains, int(result.nfev)


def update_gains(
    contributions_at_probes: np.ndarray,
    measured_at_probes: np.ndarray,
    bounds: np.ndarray | Sequence[tuple[float, float]],
    *,
    seed: int,
    fixed_at_probes: np.ndarray | None = None,
    initial_gains: np.ndarray | None = None,
) -> GainUpdate:
    """Post-process 2024 eq. 8/9: gains within ``bounds`` minimising the squared residue at the probes.

    ``contributions_at_probes`` is ``(P, G)``: at each probed value (an
    instant and an axis) the contribution in um of each gain's sub-models at
    gain 1; ``measured_at_probes`` the ``P`` probed displacements (um);
    ``fixed_at_probes`` the contribution of the sub-models whose gains stay.
    Raises :class:`ModelError` when ``P < G`` (see :func:`check_well_posed`).
    """
    problem = GainProblem.of(contributions_at_probes, measured_at_probes, fixed_at_probes)
    check_well_posed(problem.n_rows, problem.n_gains)
    limits = check_bounds(bounds, problem.n_gains)
    gains, evaluations = _minimise(problem, limits, seed)
    before = float("nan")
    if initial_gains is not None:
        before = float(
            np.sqrt(problem.sum_squares(np.asarray(initial_gains, float)) / problem.n_rows)
        )
    span = limits[:, 1] - limits[:, 0]
    at_bound = (np.abs(gains - limits[:, 0]) <= 1e-6 * span) | (
        np.abs(gains - limits[:, 1]) <= 1e-6 * span
    )
    return GainUpdate(
        gains=gains,
        bounds=limits,
        rms_after_um=float(np.sqrt(problem.sum_squares(gains) / problem.n_rows)),
        rms_before_um=before,
        n_rows=problem.n_rows,
        rank=problem.rank,
        at_bound=at_bound,
        evaluations=evaluations,
    )


def segments_between_changes(signal: np.ndarray, *, min_samples: int = 2) -> list[tuple[int, int]]:
    """Half-open ``(start, stop)`` index ranges over which ``signal`` holds one value.

    The intervals ``t_{i-1}..t_i`` of Post-process 2024 eq. 7 (between changes of
    technological conditions, e.g. of spindle speed); those shorter than
    ``min_samples`` are left out (too short to say anything about a gain).
    """
    values = np.asarray(signal, dtype=float).ravel()
    if values.size == 0:
        return []
    changes = np.flatnonzero(values[1:] != values[:-1]) + 1
    edges = np.concatenate([[0], changes, [values.size]])
    return [(int(a), int(b)) for a, b in itertools.pairwise(edges) if b - a >= min_samples]


@dataclass(frozen=True, eq=False)
class CharacteristicBounds:
    """Post-process 2024 eq. 7 per interval, and the gain range they span.

    ``segment_gains`` is ``(K, G)``, NaN where a gain's contribution is too
    small over that interval to determine it; ``segment_fit_percent`` the eq. 7
    fit at each interval's optimum; ``bounds`` the characteristic ``(G, 2)``.
    """

    segments: tuple[tuple[int, int], ...]
    segment_gains: np.ndarray
    segment_fit_percent: np.ndarray
    bounds: np.ndarray


def characteristic_bounds(
    contributions_um: np.ndarray,
    measured_um: np.ndarray,
    segments: Sequence[tuple[int, int]],
    *,
    search_bounds: np.ndarray | Sequence[tuple[float, float]] | None = None,
    fixed_um: np.ndarray | None = None,
    margin: float = 0.1,
    seed: int = 0,
) -> CharacteristicBounds:
    """Post-process 2024 eq. 7: maximise the fit on each interval, bound the gains by the optima's range.

    On interval ``i`` the fit ``(1 - ||y - y(g)|| / ||y - mean(y)||) * 100``
    is maximal where ``||y - y(g)||^2`` is minimal (the denominator does not
    depend on ``g``), so each interval is the quadratic problem of
    :class:`GainProblem` restricted to its rows. The characteristic bounds are
    ``[min - m, max + m]`` of the interval optima with ``m = margin * (max - min)``,
    clipped to ``search_bounds`` (default ``(0, 2)`` each, eq. 9).
    """
    c = np.atleast_2d(np.asarray(contributions_um, dtype=float))
    y = np.asarray(measured_um, dtype=float).ravel()
    fixed = np.zeros_like(y) if fixed_um is None else np.asarray(fixed_um, dtype=float).ravel()
    n_gains = c.shape[1]
    limits = check_bounds(
        [DEFAULT_BOUNDS] * n_gains if search_bounds is None else search_bounds, n_gains
    )
    if not segments:
        raise ModelError("no interval between changes is long enough to optimise gains on")
    gains = np.full((len(segments), n_gains), np.nan)
    fits = np.full(len(segments), np.nan)
    for i, (start, stop) in enumerate(segments):
        rows = slice(start, stop)
        problem = GainProblem.of(c[rows], y[rows], fixed[rows])
        norms = np.sqrt(np.clip(np.diag(problem.gram), 0.0, None))
        excited = norms > EXCITATION_TOLERANCE * max(float(norms.max(initial=0.0)), 1e-300)
        if problem.n_rows < n_gains or not excited.any():
            continue
        best, _ = _minimise(problem, limits, seed + i)
        gains[i] = np.where(excited, best, np.nan)
        spread = float(np.linalg.norm(y[rows] - y[rows].mean()))
        if spread > 0.0:
            fits[i] = (1.0 - np.sqrt(float(problem.sum_squares(best))) / spread) * 100.0
    bounds = limits.copy()
    for j in range(n_gains):
        column = gains[:, j][np.isfinite(gains[:, j])]
        if column.size:
            low, high = float(column.min()), float(column.max())
            widen = margin * (high - low)
            bounds[j] = (max(low - widen, limits[j, 0]), min(high + widen, limits[j, 1]))
            if bounds[j, 1] - bounds[j, 0] <= 0.0:  # a single optimum: keep a usable interval
                pad = max(margin * (limits[j, 1] - limits[j, 0]) * 0.05, 1e-6)
                bounds[j] = (max(low - pad, limits[j, 0]), min(high + pad, limits[j, 1]))
    return CharacteristicBounds(tuple((int(a), int(b)) for a, b in segments), gains, fits, bounds)
