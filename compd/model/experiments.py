"""Experiments: separate records stacked end to end, each run from its own start.

Records of different days, machines or files are not one continuous run: the
machine cooled down between them, or they were never related. Stacked into
one array for a fit, they must not be filtered through each other. So a
stacked record carries ``starts``, the index of each experiment's first
sample (``starts[0] == 0``); every filter (lag features, ARX regressors and
simulations) restarts from rest at each start, and no regressor takes a lag
across one. ``starts == (0,)`` is one record.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence

import numpy as np

from compd.errors import ModelError

#: One record: the default of every function that takes ``starts``.
ONE: tuple[int, ...] = (0,)


def spans(n_samples: int, starts: Sequence[int]) -> list[slice]:
    """The experiments' sample ranges; ``starts`` must begin at 0 and increase below ``n_samples``."""
    bounds = [int(s) for s in starts]
    if not bounds or bounds[0] != 0 or any(b <= a for a, b in itertools.pairwise(bounds)):
        raise ModelError(f"experiment starts must begin at 0 and increase, got {bounds}")
    if bounds[-1] >= n_samples:
        raise ModelError(f"an experiment starts at sample {bounds[-1]} of {n_samples}")
    return [slice(a, b) for a, b in zip(bounds, [*bounds[1:], n_samples], strict=True)]


def start_values(values: np.ndarray, starts: Sequence[int]) -> np.ndarray:
    """Each sample's reference: the first value of its experiment (of the record, for one)."""
    values = np.asarray(values)
    if len(starts) == 1:
        return values[:1]  # broadcasts
    lengths = np.diff([*starts, values.size])
    return np.repeat(values[list(starts)], lengths)


def each(
    run: Callable[[np.ndarray], np.ndarray], x: np.ndarray, starts: Sequence[int]
) -> np.ndarray:
    """``run`` applied to each experiment's rows of ``x`` (from rest at its start), stacked again."""
    if len(starts) == 1:
        return run(x)
    return np.concatenate([run(x[part]) for part in spans(len(x), starts)], axis=0)
