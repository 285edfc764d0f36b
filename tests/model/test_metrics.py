"""Metrics: fit % exactly as Horejs 2015 eq. 2, residue statistics in um, reductions."""

import math

import numpy as np
import pytest

from compd.model.metrics import Comparison, ErrorStats, fit_percent, reduction_percent


def test_perfect_model_fits_100_percent() -> None:
    """Y_hat == Y gives fit = 100 %."""
    y = np.array([0.0, 3.0, 7.0, 4.0])
    assert fit_percent(y, y) == 100.0


def test_predicting_the_mean_fits_0_percent() -> None:
    """Y_hat == mean(Y) gives fit = 0 % (the NRMSE baseline)."""
    y = np.array([1.0, 2.0, 6.0])
    assert fit_percent(y, np.full(3, 3.0)) == pytest.approx(0.0, abs=1e-12)


def test_fit_is_the_normalised_root_mean_square_error_of_eq_2() -> None:
    """A hand-computed case: ||Y - Y_hat|| = 1, ||Y - mean|| = sqrt(2) -> fit = (1 - 1/sqrt 2) * 100."""
    y = np.array([0.0, 2.0])
    assert fit_percent(y, np.array([0.0, 1.0])) == pytest.approx((1 - 1 / math.sqrt(2)) * 100)


def test_fit_can_be_negative_for_a_model_worse_than_the_mean() -> None:
    """A model that is worse than predicting the mean has a negative fit, as in MATLAB's compare."""
    y = np.array([0.0, 1.0, 0.0, 1.0])
    assert fit_percent(y, 1.0 - y) < 0.0


def test_fit_of_a_constant_measurement_is_undefined() -> None:
    """A flat measurement has no variation to reproduce: fit is NaN, not a division error."""
    assert math.isnan(fit_percent(np.ones(5), np.zeros(5)))


def test_error_stats_in_micrometres() -> None:
    """RMS, peak-to-peak, max |e| and mean of a residue."""
    stats = ErrorStats.of(np.array([-3.0, 1.0, 4.0, 2.0]))
    assert stats.rms_um == pytest.approx(math.sqrt((9 + 1 + 16 + 4) / 4))
    assert stats.peak_to_peak_um == 7.0
    assert stats.max_abs_um == 4.0
    assert stats.mean_um == 1.0


def test_comparison_reports_residue_and_uncompensated_figures() -> None:
    """Residue = Y - Y_hat (Horejs 2015 eq. 3); uncompensated = Y; reductions follow from both."""
    measured = np.array([0.0, 10.0, 20.0, 10.0])
    predicted = np.array([0.0, 9.0, 18.0, 11.0])
    c = Comparison.of("disp_z_um", measured, predicted)
    assert c.residue.max_abs_um == 2.0
    assert c.uncompensated.peak_to_peak_um == 20.0
    assert c.peak_to_peak_reduction_percent == pytest.approx(85.0)
    assert c.rms_reduction_percent == pytest.approx(
        (1 - c.residue.rms_um / c.uncompensated.rms_um) * 100
    )
    keys = c.as_dict()
    assert {
        "fit_percent",
        "rms_um",
        "peak_to_peak_um",
        "max_abs_um",
        "uncompensated_rms_um",
    } <= set(keys)


def test_reduction_of_nothing_is_undefined() -> None:
    """No uncompensated error means no reduction figure."""
    assert math.isnan(reduction_percent(0.0, 0.0))
