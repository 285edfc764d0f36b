"""Collinear input groups: sensors that move together carry one piece of information.

Sixteen temperatures on one machine are mostly a few heat sources seen from
several places; a least-squares fit gives such a group large gains of opposite
sign that cancel on the calibration record and not on the next. The groups
are found by complete-linkage clustering on ``1 - |r|`` (``r``: the
correlation of the inputs' changes), so every pair inside a group correlates
at least ``min_abs_correlation``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import scipy.cluster.hierarchy
import scipy.spatial.distance

#: Pairs at least this correlated are near-duplicates for identification.
MIN_ABS_CORRELATION = 0.98


def collinear_groups(
    u: np.ndarray, names: Sequence[str], min_abs_correlation: float = MIN_ABS_CORRELATION
) -> list[tuple[str, ...]]:
    """Groups of two or more inputs (columns of ``u``) whose every pair has ``|r| >= min_abs_correlation``."""
    u = np.asarray(u, dtype=float)
    if u.shape[1] < 2:
        return []
    with np.errstate(invalid="ignore", divide="ignore"):
        r = np.corrcoef(u, rowvar=False)
    r = np.nan_to_num(r, nan=0.0)
    distance = np.clip(1.0 - np.abs(r), 0.0, 2.0)
    np.fill_diagonal(distance, 0.0)
    tree = scipy.cluster.hierarchy.linkage(
        scipy.spatial.distance.squareform(distance, checks=False), method="complete"
    )
    labels = scipy.cluster.hierarchy.fcluster(
        tree, t=1.0 - min_abs_correlation, criterion="distance"
    )
    groups = [
        tuple(n for n, label in zip(names, labels, strict=True) if label == k)
        for k in np.unique(labels)
    ]
    return sorted((g for g in groups if len(g) > 1), key=lambda g: (-len(g), g))


def contribution_shares(contributions: np.ndarray) -> np.ndarray:
    """Each column's RMS as a share of the sum of all columns' RMS (0..1): who carries the output."""
    rms = np.sqrt(np.mean(np.square(np.asarray(contributions, dtype=float)), axis=0))
    total = rms.sum()
    return rms / total if total > 0.0 else np.zeros_like(rms)
