"""Min/max decimation of plotted traces."""

import itertools

import numpy as np
import pytest

from compd.report.decimate import minmax_indices


def test_short_record_is_kept_whole() -> None:
    """A record of at most two samples per bucket is drawn in full."""
    y = np.arange(10.0)
    np.testing.assert_array_equal(minmax_indices([y], n_buckets=5), np.arange(10))


def test_every_bucket_keeps_its_minimum_and_maximum() -> None:
    """Each bucket's smallest and largest value survive, so no peak is lost on screen."""
    rng = np.random.default_rng(1)
    y = np.cumsum(rng.normal(size=10_000))
    kept = minmax_indices([y], n_buckets=100)
    edges = np.linspace(0, len(y), 101).astype(int)
    for a, b in itertools.pairwise(edges):
        inside = y[kept[(kept >= a) & (kept < b)]]
        assert inside.min() == y[a:b].min() and inside.max() == y[a:b].max()
    assert kept[0] == 0 and kept[-1] == len(y) - 1
    assert len(kept) <= 2 * 100 + 2


def test_indices_are_shared_by_all_arrays() -> None:
    """Several traces get one sorted index set holding every trace's extremes (stacked plots stay aligned)."""
    t = np.linspace(0.0, 50.0, 20_000)
    a, b = np.sin(t), np.cos(3.0 * t)
    kept = minmax_indices([a, b], n_buckets=50)
    assert np.all(np.diff(kept) > 0)
    assert a[kept].max() == a.max() and b[kept].min() == b.min()
    assert len(kept) <= 2 * 2 * 50 + 2


def test_rejects_arrays_of_different_lengths() -> None:
    """Traces on one time axis must have one length."""
    with pytest.raises(ValueError, match="differ in length"):
        minmax_indices([np.zeros(5000), np.zeros(4999)])
