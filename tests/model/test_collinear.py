"""Collinear input groups and who carries the output."""

from __future__ import annotations

import numpy as np

from compd.model.collinear import collinear_groups, contribution_shares


def test_near_duplicates_are_grouped_and_independent_sensors_are_not() -> None:
    """Two sensors on one node (a Pt100 offset apart) form a group; an unrelated one stays alone."""
    rng = np.random.default_rng(0)
    node = np.cumsum(rng.normal(size=2000))
    u = np.column_stack(
        [node, node + 0.3 + rng.normal(0, 0.05, 2000), np.cumsum(rng.normal(size=2000))]
    )
    assert collinear_groups(u, ["a", "b", "c"]) == [("a", "b")]


def test_a_single_input_has_no_group() -> None:
    """One input cannot be collinear with anything."""
    assert collinear_groups(np.arange(10.0)[:, None], ["a"]) == []


def test_shares_sum_to_one_and_follow_the_rms() -> None:
    """A column three times as large carries three quarters of the output."""
    shares = contribution_shares(np.column_stack([np.ones(10), 3 * np.ones(10)]))
    assert np.allclose(shares, [0.25, 0.75])
