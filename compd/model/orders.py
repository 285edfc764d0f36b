"""Automatic ARX orders and input delays, judged by free-run simulation on held-back data.

A one-step-ahead prediction fit is near 100 % for almost any order on slow
thermal data (``y(k-1)`` predicts ``y(k)`` well), so it cannot choose an
order. Each candidate is instead estimated on the first part of the record
and *simulated* over the whole record from rest; its score is the Horejs 2015
eq. 2 fit on the held-back last part, which the estimate never saw.

The normal equations are built once, in the difference basis of
:mod:`compd.model.arx`, for the largest orders and every candidate delay;
each candidate solves a sub-block, so a candidate costs one small solve and
one simulation.

Search: first a common order ``n`` for everything (``na = nb_i = n``,
``nk_i = 1``), then each input's ``nb_i`` and ``nk_i`` in turn with the rest
held, then ``na`` again. Among candidates whose validation error
``100 - fit`` is within :data:`TOLERANCE_POINTS` plus
:data:`TOLERANCE_RELATIVE` of the best, the one with the fewest parameters
wins (an extra lag that buys nothing on unseen data is left out).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol, TypeVar

import numpy as np

from compd.model.arx import ArxParameters, Regression, build_regression, simulate_arx, solve_arx
from compd.model.metrics import fit_percent

#: Fraction of the record used for estimation; the rest is held back for validation.
ESTIMATION_FRACTION = 2.0 / 3.0
#: A simpler candidate wins while its validation error is within this many fit points ...
TOLERANCE_POINTS = 0.01
#: ... plus this fraction of the best candidate's validation error (100 - fit).
TOLERANCE_RELATIVE = 0.01

#: Called with the stage name ("ARX order search") and the fraction of it done (0..1).
SearchProgress = Callable[[str, float], None]


class Scored(Protocol):
    """What :func:`choose` compares: parameter count, validation error, usability."""

    @property
    def size(self) -> int: ...

    @property
    def error(self) -> float: ...

    @property
    def usable(self) -> bool: ...


ScoredT = TypeVar("ScoredT", bound=Scored)


@dataclass(frozen=True)
class ArxCandidate:
    """One set of orders, its estimate on the estimation part and its validation fit (%)."""

    na: int
    nb: tuple[int, ...]
    nk: tuple[int, ...]
    parameters: ArxParameters | None  # None when the estimate was unstable
    validation_fit_percent: float

    @property
    def size(self) -> int:
        return self.na + sum(self.nb)

    @property
    def error(self) -> float:
        return 100.0 - self.validation_fit_percent

    @property
    def usable(self) -> bool:
        return self.parameters is not None and bool(np.isfinite(self.error))


@dataclass(frozen=True)
class OrderSearch:
    """The chosen orders and every candidate tried (for reports)."""

    best: ArxCandidate
    tried: tuple[ArxCandidate, ...]
    split: int
    estimation: Regression
    validation: Regression | None


def split_index(n_samples: int) -> int:
    return int(n_samples * ESTIMATION_FRACTION)


def choose(candidates: Sequence[ScoredT]) -> ScoredT:
    """The simplest candidate within tolerance of the best validation error (ties: lower error)."""
    stable = [c for c in candidates if c.usable]
    if not stable:
        return min(candidates, key=lambda c: c.size)
    best_error = min(c.error for c in stable)
    limit = best_error + TOLERANCE_POINTS + TOLERANCE_RELATIVE * abs(best_error)
    eligible = [c for c in stable if c.error <= limit]
    return min(eligible, key=lambda c: (c.size, c.error))


def search_arx(
    y: np.ndarray,
    inputs: np.ndarray,
    *,
    na_max: int = 3,
    nb_max: int = 3,
    delays: Sequence[int] = (0, 1, 2),
    progress: SearchProgress | None = None,
    first_sample: int = 0,
) -> OrderSearch:
    """Choose ``na``, ``nb_i``, ``nk_i`` by validation simulation fit (see the module docstring).

    Only samples from ``first_sample`` on are split into estimation and
    validation parts; every candidate is still simulated from sample 0.
    """
    y = np.asarray(y, dtype=float)
    inputs = np.asarray(inputs, dtype=float).reshape(y.size, -1)
    n_inputs = inputs.shape[1]
    split = first_sample + split_index(y.size - first_sample)
    estimation, validation = build_regression(
        y,
        inputs,
        na_max=na_max,
        nb_max=nb_max,
        delays=delays,
        split=split,
        first_sample=first_sample,
    )
    held_back = y[split:]
    tried: list[ArxCandidate] = []
    planned = na_max + n_inputs * len(delays) * nb_max + na_max

    def evaluate(na: int, nb: Sequence[int], nk: Sequence[int]) -> ArxCandidate:
        for seen in tried:
            if seen.na == na and seen.nb == tuple(nb) and seen.nk == tuple(nk):
                return seen
        parameters: ArxParameters | None = solve_arx(estimation, na, nb, nk)
        score = -np.inf
        if parameters is not None and parameters.stable():
            simulated = simulate_arx(parameters, inputs)
            score = fit_percent(held_back, simulated[split:])
            if not np.isfinite(score):
                score = -np.inf
        else:
            parameters = None
        candidate = ArxCandidate(na, tuple(nb), tuple(nk), parameters, float(score))
        tried.append(candidate)
        if progress is not None:
            progress("ARX order search", min(len(tried) / planned, 1.0))
        return candidate

    current = choose(
        [evaluate(n, [min(n, nb_max)] * n_inputs, [1] * n_inputs) for n in range(1, na_max + 1)]
    )
    for i in range(n_inputs):
        options = [current]
        for delay in delays:
            for count in range(1, nb_max + 1):
                nb, nk = list(current.nb), list(current.nk)
                nb[i], nk[i] = count, delay
                options.append(evaluate(current.na, nb, nk))
        current = choose(options)
    current = choose(
        [current, *(evaluate(n, current.nb, current.nk) for n in range(1, na_max + 1))]
    )
    return OrderSearch(current, tuple(tried), split, estimation, validation)
