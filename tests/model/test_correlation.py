"""Residue correlations: FFT results equal direct sums, and Bartlett bounds account for autocorrelation."""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from compd.model.correlation import Z99, correlate, fft_size, whiteness_exceedances

N = 4000
MAX_LAG = 40


def direct(a: np.ndarray, b: np.ndarray, lags: int) -> np.ndarray:
    """sum_t a(t) b(t - k) / sqrt(sum a^2 sum b^2) for k = 0..lags, mean-removed, by np.correlate."""
    a, b = a - a.mean(), b - b.mean()
    full = np.correlate(a, b, mode="full")  # index N-1 is lag 0, N-1+k is a(t+k) b(t)
    return full[len(a) - 1 : len(a) + lags] / np.sqrt((a @ a) * (b @ b))


@pytest.fixture(scope="module")
def series() -> dict[str, np.ndarray]:
    rng = np.random.default_rng(11)
    return {
        "white": rng.normal(size=N),
        "other_white": rng.normal(size=N),
        "walk": np.cumsum(rng.normal(size=N)),
        "other_walk": np.cumsum(rng.normal(size=N)),
    }


def test_correlations_equal_direct_sums(series: dict) -> None:
    """Auto- and cross-correlations from the FFT equal np.correlate's direct sums at every lag."""
    inputs = np.vstack([series["white"], series["walk"]])
    result = correlate(series["other_walk"], inputs, MAX_LAG)
    assert_allclose(
        result.autocorrelation,
        direct(series["other_walk"], series["other_walk"], MAX_LAG),
        atol=1e-12,
    )
    for i in range(2):
        assert_allclose(
            result.cross[i], direct(series["other_walk"], inputs[i], MAX_LAG), atol=1e-12
        )


def test_cross_bound_is_bartletts_sum(series: dict) -> None:
    """The cross bound is 2.576 sqrt((1/N) sum_{|m|<=M} r_ee(m) r_uu(m)), as written out over lags."""
    e, u = series["walk"], series["other_walk"]
    result = correlate(e, u[None, :], MAX_LAG)
    r_ee, r_uu = direct(e, e, MAX_LAG), direct(u, u, MAX_LAG)
    expected = Z99 * np.sqrt((r_ee[0] * r_uu[0] + 2.0 * np.sum(r_ee[1:] * r_uu[1:])) / N)
    assert_allclose(result.cross_bound[0], expected, rtol=1e-9)


def test_autocorrelation_bound_is_bartletts_cumulative_formula(series: dict) -> None:
    """At lag k the bound is 2.576 sqrt((1 + 2 sum_{m<k} r(m)^2) / N); at lag 1 the white-noise bound."""
    result = correlate(series["walk"], series["white"][None, :], MAX_LAG)
    r = result.autocorrelation
    for k in (1, 2, 10, MAX_LAG):
        expected = Z99 * np.sqrt((1.0 + 2.0 * np.sum(r[1:k] ** 2)) / N)
        assert_allclose(result.autocorrelation_bound[k], expected, rtol=1e-12)
    assert result.autocorrelation_bound[1] == pytest.approx(result.naive_bound)


def test_slow_independent_walk_is_flagged_by_the_naive_bound_but_not_by_bartletts(
    series: dict,
) -> None:
    """Two independent random walks correlate far beyond 2.576/sqrt(N) but stay inside the Bartlett bound."""
    result = correlate(series["walk"], series["other_walk"][None, :], N // 4)
    peak = np.max(np.abs(result.cross[0]))
    assert peak > result.naive_bound  # the naive test would call this a cause
    assert result.cross_bound[0] > 5 * result.naive_bound  # Bartlett widens it for slow signals
    assert peak < result.cross_bound[0]  # and does not


def test_for_white_series_the_bartlett_bound_is_close_to_the_naive_one(series: dict) -> None:
    """With white residue and input the Bartlett cross bound reduces to about 2.576/sqrt(N)."""
    result = correlate(series["white"], series["other_white"][None, :], MAX_LAG)
    assert result.cross_bound[0] == pytest.approx(result.naive_bound, rel=0.1)


def test_white_noise_passes_and_a_walk_fails_the_whiteness_test(series: dict) -> None:
    """White noise leaves its autocorrelation bounds no more often than chance allows; a random walk does."""
    outside, allowed = whiteness_exceedances(
        correlate(series["white"], series["walk"][None, :], 200)
    )
    assert outside <= allowed
    outside, allowed = whiteness_exceedances(
        correlate(series["walk"], series["white"][None, :], 200)
    )
    assert outside > allowed


def test_a_constant_input_has_no_correlation(series: dict) -> None:
    """A constant input gives a zero cross-correlation and an undefined (NaN) bound, not an error."""
    result = correlate(series["white"], np.ones((1, N)), MAX_LAG)
    assert not result.cross[0].any() and np.isnan(result.cross_bound[0])


@pytest.mark.parametrize("minimum", [1, 7, 100, 16_385, 93_600, 295_200, 612_000])
def test_fft_size_is_long_enough_and_5_smooth(minimum: int) -> None:
    """The FFT length covers the padded series and has no prime factor above 5."""
    size = fft_size(minimum)
    assert minimum <= size <= 1.25 * minimum + 8
    for prime in (2, 3, 5):
        while size % prime == 0:
            size //= prime
    assert size == 1
