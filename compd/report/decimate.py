"""Min/max decimation: fewer points to draw, the same envelope on screen.

A 24 h record at 1 Hz has 86,400 samples per trace; a browser draws a few
thousand SVG points per trace quickly and a screen has about a thousand
pixels across. Keeping, in each of ``n_buckets`` equal runs of samples, the
sample with the smallest and the one with the largest value (in time order)
keeps every peak and trough a reader would see at full resolution. Numbers in
the report never come from decimated data, only the drawn lines do.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

#: Buckets per trace: two points each, so at most 1,000 drawn points per trace,
#: about one per pixel column of a report's plot area (about 1,030 px wide at
#: the page's 1,200 px), a minimum and a maximum every two: the envelope a
#: reader sees. (1,600 points drew the same picture; a 16 h record's report
#: with two models carried 0.74 MB of lines, 0.46 MB now.)
DEFAULT_BUCKETS = 500


def minmax_indices(values: Sequence[np.ndarray], n_buckets: int = DEFAULT_BUCKETS) -> np.ndarray:
    """Sorted sample indices that keep each bucket's min and max of every array in ``values``.

    All arrays share one time axis and get the same indices (the union over
    arrays), so traces drawn stacked or side by side stay aligned. The first
    and last samples are always kept. A record of at most ``2 * n_buckets``
    samples is returned whole.
    """
    if n_buckets < 1:
        raise ValueError(f"n_buckets must be at least 1, got {n_buckets}")
    arrays = [np.asarray(v, dtype=float) for v in values]
    n = len(arrays[0]) if arrays else 0
    if any(len(a) != n for a in arrays):
        raise ValueError(f"arrays to decimate differ in length: {[len(a) for a in arrays]}")
    if n <= 2 * n_buckets:
        return np.arange(n)
    edges = np.linspace(0, n, n_buckets + 1).astype(int)
    starts = edges[:-1]
    kept = [np.array([0, n - 1])]
    for a in arrays:
        # reduceat gives each bucket's min/max; the argmin/argmax inside a
        # bucket come from comparing each sample with its bucket's extreme.
        bucket = np.repeat(np.arange(n_buckets), np.diff(edges))
        for extreme in (np.minimum, np.maximum):
            per_bucket = extreme.reduceat(a, starts)
            hits = np.flatnonzero(a == per_bucket[bucket])
            # first hit in each bucket
            first = np.unique(bucket[hits], return_index=True)[1]
            kept.append(hits[first])
    return np.unique(np.concatenate(kept))
