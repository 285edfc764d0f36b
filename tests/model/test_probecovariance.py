"""The probe update's covariance: the random walk kept as a scalar, changes undone exactly."""

import numpy as np
import pytest

from compd.model.probecovariance import DriftingCovariance


def _spd(p: int, seed: int) -> np.ndarray:
    a = np.random.default_rng(seed).normal(size=(p, p))
    matrix: np.ndarray = a @ a.T + p * np.eye(p)
    return matrix


def test_the_matrix_is_stored_plus_the_drift_in_the_priors_shape_minus_each_step() -> None:
    """P = P_start + w P0 - sum v v': what the update would have built as one matrix."""
    prior, start = _spd(5, 0), _spd(5, 1)
    p = DriftingCovariance.of(start, prior)
    v1, v2 = np.arange(5.0) / 10, np.ones(5) / 3
    p.drift_weight += 0.2
    p.downdate(v1)
    p.drift_weight += 0.1
    p.downdate(v2)
    expected = start + 0.3 * prior - np.outer(v1, v1) - np.outer(v2, v2)
    np.testing.assert_allclose(p.matrix(), expected, rtol=1e-12)
    x = np.linspace(-1, 1, 5)
    np.testing.assert_allclose(p.times(x), expected @ x, rtol=1e-12)
    assert np.array_equal(p.matrix(), p.matrix().T)


def test_a_snapshot_is_put_back_exactly_after_several_changes() -> None:
    """A widening and two steps after a snapshot, then put_back: the very same numbers as before."""
    p = DriftingCovariance.of(_spd(4, 2), _spd(4, 3))
    p.downdate(np.full(4, 0.5))  # an earlier probe: not part of what is undone
    before = p.matrix()
    token = p.snapshot()
    p.add_to_last(2.0)
    p.downdate(np.array([1.0, 0.0, 0.5, 0.2]))
    p.downdate(np.array([0.1, 0.3, 0.0, 0.2]))
    p.put_back(token)
    assert np.array_equal(p.matrix(), before)
    p.downdate(np.full(4, 0.1))  # and it goes on from there
    np.testing.assert_allclose(p.matrix(), before - 0.01, rtol=1e-12)


def test_nested_snapshots_of_the_same_state_both_put_it_back() -> None:
    """A learner's snapshot around its update's own: the outer one still restores after the inner succeeded."""
    p = DriftingCovariance.of(_spd(3, 4), _spd(3, 5))
    before = p.matrix()
    outer = p.snapshot()
    p.snapshot()  # the update's own, at the same state
    p.downdate(np.array([0.5, 0.5, 0.5]))
    p.put_back(outer)
    assert np.array_equal(p.matrix(), before)


def test_an_older_snapshot_than_the_last_kept_state_is_refused() -> None:
    """Put back a state two snapshots old: an error, not a silent wrong covariance."""
    p = DriftingCovariance.of(_spd(3, 6), _spd(3, 7))
    old = p.snapshot()
    p.downdate(np.array([0.1, 0.2, 0.3]))
    p.snapshot()
    p.downdate(np.array([0.3, 0.2, 0.1]))
    with pytest.raises(RuntimeError, match="snapshot"):
        p.put_back(old)


def test_a_step_that_would_overflow_is_refused_and_changes_nothing() -> None:
    """A step of 1e200 (its square beyond float's range) or NaN: ValueError, the matrix as it was."""
    p = DriftingCovariance.of(_spd(3, 8), _spd(3, 9))
    before = p.matrix()
    for bad in (np.array([1e200, 0.0, 0.0]), np.array([np.nan, 0.0, 0.0])):
        with pytest.raises(ValueError, match="not a finite number"):
            p.downdate(bad)
    assert np.array_equal(p.matrix(), before) and p.finite()
