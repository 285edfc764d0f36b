"""MISO ARX: regressors in the difference basis, least squares, stability, simulation."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.signal
from numpy.testing import assert_allclose

from compd.errors import ModelError
from compd.model.arx import (
    build_regression,
    difference_matrix,
    differences,
    fit_arx,
    simulate_arx,
    solve_arx,
    solve_scaled,
)
from tests.model.thermal_cases import held_levels, make_case, thermal_second_order

TS = 10.0


@pytest.fixture(scope="module")
def common_denominator_case():
    """Two inputs through one second-order denominator (tau 20 min and 2 h), noise-free."""
    a = np.poly(np.exp(-TS / np.array([1200.0, 7200.0])))
    b0 = np.array([0.0, 2.0e-3, -1.2e-3])
    b1 = np.array([0.0, -0.7e-3, 0.9e-3])
    return make_case([(b0, a), (b1, a)], hours=40, sample_time_s=TS)


def test_differences_match_numpy_diff():
    """Column j of ``differences`` is the j-th backward difference of x delayed by ``delay``."""
    x = np.random.default_rng(1).normal(size=50).cumsum()
    columns = differences(x, 2, 3, 5)
    for j in range(3):
        expected = np.diff(x, n=j)[5 - 2 - j : 50 - 2 - j]
        assert_allclose(columns[:, j], expected, rtol=0, atol=1e-12)


def test_difference_matrix_maps_difference_coefficients_to_lags():
    """``T @ c`` gives the raw-lag weights of ``sum_j c_j Delta^j x``."""
    x = np.random.default_rng(2).normal(size=40)
    c = np.array([0.3, -1.1, 0.7])
    columns = differences(x, 0, 3, 2)
    raw = difference_matrix(3) @ c
    lagged = np.column_stack([x[2 - m : 40 - m] for m in range(3)])
    assert_allclose(columns @ c, lagged @ raw, atol=1e-12)


def test_arx_recovers_noise_free_parameters(common_denominator_case):
    """On noise-free data from a true ARX system with hour-long poles, least squares returns its coefficients."""
    case = common_denominator_case
    fitted = fit_arx(case.y, case.inputs, 2, [2, 2], [1, 1])
    assert_allclose(fitted.a, case.a[0], rtol=1e-9)
    for b_fit, b_true in zip(fitted.full_numerators(), case.b, strict=True):
        assert_allclose(b_fit, b_true, rtol=1e-6, atol=1e-12)


def test_arx_matches_numpy_lstsq_on_raw_lags():
    """The difference-basis normal equations give np.linalg.lstsq's solution on the raw lags."""
    b, a = thermal_second_order((600.0, 2400.0), 1.5, 0.4, TS)
    case = make_case([(b, a)], hours=20, sample_time_s=TS, noise_fraction=0.05, seed=3)
    y, u = case.y, case.inputs[:, 0]
    first = 2
    raw = np.column_stack([-y[1:-1], -y[:-2], u[1:-1], u[:-2]])
    theta = np.linalg.lstsq(raw, y[first:], rcond=None)[0]
    fitted = fit_arx(y, case.inputs, 2, [2], [1])
    assert_allclose(fitted.a[1:], theta[:2], rtol=1e-7)
    assert_allclose(fitted.b[0], theta[2:], rtol=1e-6)


def test_lower_orders_are_sub_blocks_of_one_regression(common_denominator_case):
    """Solving a sub-block of the largest-order normal equations equals building them for that order."""
    case = common_denominator_case
    big, _ = build_regression(case.y, case.inputs, na_max=3, nb_max=3, delays=(0, 1, 2))
    small, _ = build_regression(case.y, case.inputs, na_max=2, nb_max=2, delays=(1,))
    from_big = solve_arx(big, 2, [2, 1], [1, 1])
    # The two regressions start at different samples (3 vs 2): equal to rounding of one row.
    from_small = solve_arx(small, 2, [2, 1], [1, 1])
    assert_allclose(from_big.a, from_small.a, rtol=1e-5)


def test_split_regressions_add_up_to_the_whole(common_denominator_case):
    """Normal equations of the estimation and validation parts sum to those of the whole record."""
    case = common_denominator_case
    whole, _ = build_regression(case.y, case.inputs, na_max=2, nb_max=2, delays=(1,))
    first, second = build_regression(
        case.y, case.inputs, na_max=2, nb_max=2, delays=(1,), split=5000
    )
    assert second is not None
    assert_allclose((first + second).gram, whole.gram, rtol=1e-12)


def test_unstable_fixed_order_is_an_error_with_advice():
    """A record that grows without bound gives an unstable ARX model, refused with what to do instead."""
    rng = np.random.default_rng(4)
    u = held_levels(rng, 3000, TS)
    y = scipy.signal.lfilter([0.0, 1.0], [1.0, -1.002], u) + rng.normal(0, 1e-3, u.size)
    with pytest.raises(ModelError, match=r"unstable.*lower order"):
        fit_arx(y, u[:, None], 1, [1], [1])


def test_simulation_is_the_sum_of_one_lfilter_per_input(common_denominator_case):
    """``simulate_arx`` is ``sum_i lfilter(B_i q^-nk_i, A, u_i)`` from rest."""
    case = common_denominator_case
    fitted = fit_arx(case.y, case.inputs, 2, [2, 2], [1, 1])
    expected = sum(
        scipy.signal.lfilter(b, fitted.a, case.inputs[:, i])
        for i, b in enumerate(fitted.full_numerators())
    )
    assert_allclose(simulate_arx(fitted, case.inputs), expected, rtol=1e-9, atol=1e-9)


def test_rank_deficient_normal_equations_give_the_minimum_norm_solution():
    """Two identical regressors share the weight instead of exploding to opposite huge values."""
    x = np.random.default_rng(5).normal(size=(100, 1))
    columns = np.hstack([x, x])
    target = 3.0 * x[:, 0]
    solution = solve_scaled(columns.T @ columns, columns.T @ target)
    assert_allclose(solution, [1.5, 1.5], rtol=1e-9)
