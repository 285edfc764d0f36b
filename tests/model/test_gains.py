"""Gain update core (Post-process 2024 eq. 6-9): exact recovery, bounds, eq. 7 intervals, and linearity."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.optimize import lsq_linear

from compd.errors import ModelError
from compd.model import InputSpec, Model, Output, SubModel, compile_model
from compd.model.gains import (
    GainProblem,
    characteristic_bounds,
    segments_between_changes,
    update_gains,
)
from compd.model.run import simulate
from tests.model.conftest import first_order, gate_on


def _contributions(rng: np.random.Generator, rows: int, gains: int) -> np.ndarray:
    """Smooth, positive, distinct columns, like thermal contributions sampled at probe instants."""
    t = np.linspace(0.0, 1.0, rows)[:, None]
    return 10.0 * (1.0 - np.exp(-t * (1.0 + np.arange(gains)))) + rng.normal(0, 0.5, (rows, gains))


def test_recovers_known_gains_from_exact_probes() -> None:
    """With noise-free probes the optimum is the true gain vector, as bounded least squares finds it."""
    rng = np.random.default_rng(1)
    c = _contributions(rng, 12, 3)
    fixed = rng.normal(0, 2, 12)
    true = np.array([0.4, 1.3, 0.9])
    result = update_gains(
        c, fixed + c @ true, [(0, 2)] * 3, seed=3, fixed_at_probes=fixed, initial_gains=np.ones(3)
    )
    assert_allclose(result.gains, true, rtol=1e-6)
    assert result.rms_after_um < 1e-5 < result.rms_before_um
    assert result.well_determined and not result.at_bound.any()


def test_bounds_are_respected_and_the_constrained_optimum_is_found() -> None:
    """Gains outside the bounds end on them, at scipy's bounded least-squares optimum."""
    rng = np.random.default_rng(2)
    c = _contributions(rng, 8, 2)
    y = c @ np.array([2.6, 0.2]) + rng.normal(0, 0.1, 8)
    bounds = [(0.5, 1.1), (0.0, 2.0)]
    result = update_gains(c, y, bounds, seed=0)
    reference = lsq_linear(c, y, bounds=([0.5, 0.0], [1.1, 2.0])).x
    assert_allclose(result.gains, reference, atol=1e-6)
    assert result.gains[0] == pytest.approx(1.1)
    assert result.at_bound.tolist() == [True, False]


def test_fewer_probes_than_gains_is_refused_with_advice() -> None:
    """One probe cannot set two gains: the error says how many probes are needed."""
    with pytest.raises(ModelError, match="probe at least 2 times"):
        update_gains(np.ones((1, 2)), np.ones(1), [(0, 2), (0, 2)], seed=0)


def test_proportional_contributions_are_flagged_as_not_determined() -> None:
    """Two gains whose contributions are proportional at the probes are reported as rank 1."""
    column = np.linspace(1.0, 5.0, 6)
    result = update_gains(np.column_stack([column, 2 * column]), 3 * column, [(0, 2)] * 2, seed=0)
    assert result.rank == 1 and not result.well_determined
    assert result.rms_after_um < 1e-6


def test_the_objective_equals_a_full_re_simulation() -> None:
    """Gains scale contributions linearly: fixed + C g equals re-simulating the model with gains g."""
    cooling = SubModel(
        "cooling", "cooling", InputSpec("T_degC", reference=0.0), first_order(2.0, 0.97)
    )
    heating = SubModel(
        "heating", "heating", InputSpec("T_degC", reference=0.0), first_order(-1.0, 0.9),
        gate=gate_on(),
    )  # fmt: skip
    ambient = SubModel(
        "ambient", "ambient", InputSpec("A_degC", reference=0.0), first_order(0.5, 0.99)
    )
    model = Model("m", 1.0, (Output("disp_z_um", (cooling, heating, ambient)),))
    rng = np.random.default_rng(4)
    n = 600
    signals = np.column_stack(
        [
            np.cumsum(rng.normal(0, 0.1, n)),
            (np.arange(n) % 200 < 120) * 3000.0,
            np.cumsum(rng.normal(0, 0.05, n)),
        ]
    )
    unit = compile_model(model)
    assert unit.signals == ("T_degC", "speed_rpm", "A_degC")
    parts = simulate(unit, signals, unit.rest_state(signals[0])).contributions
    gains = np.array([1.37, 0.42])
    scaled = Model(
        "m",
        1.0,
        (
            Output(
                "disp_z_um",
                (
                    dataclasses.replace(cooling, gain=gains[0]),
                    dataclasses.replace(heating, gain=gains[1]),
                    ambient,
                ),
            ),
        ),
    )
    compiled = compile_model(scaled)
    direct = simulate(compiled, signals, compiled.rest_state(signals[0])).outputs[:, 0]
    assert_allclose(parts[:, 2] + parts[:, :2] @ gains, direct, rtol=1e-12, atol=1e-12)

    probes = np.arange(50, n, 75)
    measured = direct[probes] + rng.normal(0, 0.05, probes.size)
    problem = GainProblem.of(parts[probes, :2], measured, parts[probes, 2])
    assert float(problem.sum_squares(gains)) == pytest.approx(
        float(np.sum((measured - direct[probes]) ** 2)), rel=1e-9
    )
    candidates = np.array([[1.0, 1.37, 0.2], [1.0, 0.42, 1.9]])
    one_by_one = [float(problem.sum_squares(candidates[:, s])) for s in range(3)]
    assert_allclose(problem.sum_squares(candidates), one_by_one, rtol=1e-12)


def test_segments_are_the_intervals_of_constant_signal() -> None:
    """Intervals run between changes of the signal; too-short ones are left out."""
    speed = np.array([0, 0, 0, 500, 500, 800, 800, 800, 800, 0.0])
    assert segments_between_changes(speed, min_samples=2) == [(0, 3), (3, 5), (5, 9)]
    assert segments_between_changes(speed, min_samples=1)[-1] == (9, 10)


def test_characteristic_bounds_span_the_per_interval_optima() -> None:
    """Eq. 7: each interval's optimum is its true gain vector; the bounds are their range plus a margin."""
    rng = np.random.default_rng(5)
    n_per, truth = 40, np.array([[0.6, 1.0], [0.9, 0.7], [1.2, 0.8]])
    c = np.vstack([_contributions(rng, n_per, 2) for _ in truth])
    y = np.concatenate([c[i * n_per : (i + 1) * n_per] @ g for i, g in enumerate(truth)])
    segments = [(i * n_per, (i + 1) * n_per) for i in range(len(truth))]
    result = characteristic_bounds(c, y, segments, margin=0.1, seed=1)
    assert_allclose(result.segment_gains, truth, atol=1e-6)
    assert_allclose(result.segment_fit_percent, 100.0, atol=1e-3)
    assert_allclose(result.bounds, [[0.54, 1.26], [0.67, 1.03]], atol=1e-6)


def test_characteristic_bounds_skip_a_gain_an_interval_does_not_excite() -> None:
    """A gain whose contribution is zero on an interval gets no optimum there (NaN), not a guess."""
    rng = np.random.default_rng(6)
    c = _contributions(rng, 60, 2)
    c[:30, 1] = 0.0
    y = c[:, 0] * 0.8 + c[:, 1] * 1.5
    result = characteristic_bounds(c, y, [(0, 30), (30, 60)], seed=0)
    assert np.isnan(result.segment_gains[0, 1])
    assert_allclose(result.segment_gains[1], [0.8, 1.5], atol=1e-6)
