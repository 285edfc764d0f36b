"""MISO output-error: separate denominators, fitted on the free-run simulation error."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from compd.errors import ModelError
from compd.model.arx import fit_arx, simulate_arx
from compd.model.metrics import fit_percent
from compd.model.oe import (
    OeParameters,
    admissible,
    fit_oe,
    oe_from_arx,
    simulate_oe,
    steiglitz_mcbride,
)
from tests.model.thermal_cases import make_case, thermal_second_order

TS = 10.0


@pytest.fixture(scope="module")
def noisy_case():
    """Three inputs, each through its own second-order TF (tau 20 min - 2 h), 1 % output noise, 80 h at 10 s."""
    tfs = [
        thermal_second_order((1200.0, 5400.0), 2.0, 0.3, TS),
        thermal_second_order((2400.0, 7200.0), -1.5, 0.6, TS),
        thermal_second_order((1500.0, 3600.0), 1.0, 0.5, TS),
    ]
    return make_case(tfs, hours=80, sample_time_s=TS, noise_fraction=0.01, seed=7)


@pytest.fixture(scope="module")
def noisy_fit(noisy_case):
    case = noisy_case
    arx = fit_arx(case.y, case.inputs, 2, [2, 2, 2], [1, 1, 1])
    start = steiglitz_mcbride(case.y, case.inputs, arx)
    result = fit_oe(case.y, case.inputs, oe_from_arx(start.a, start.b, start.nk, [2, 2, 2]))
    return arx, start, result


def test_arx_is_biased_and_oe_reaches_the_true_models_fit(noisy_case, noisy_fit):
    """With output noise ARX simulates clearly worse than the truth; OE comes within 0.05 points of it."""
    case = noisy_case
    arx, _, result = noisy_fit
    true_fit = fit_percent(case.y, case.y_true)
    arx_fit = fit_percent(case.y, simulate_arx(arx, case.inputs))
    oe_fit = fit_percent(case.y, simulate_oe(result.parameters, case.inputs))
    assert arx_fit < true_fit - 2.0
    assert oe_fit > true_fit - 0.05


def test_steiglitz_mcbride_improves_the_arx_start(noisy_case, noisy_fit):
    """The Steiglitz-McBride start simulates at least as well as the ARX estimate it came from."""
    case = noisy_case
    arx, start, _ = noisy_fit
    assert fit_percent(case.y, simulate_arx(start, case.inputs)) >= fit_percent(
        case.y, simulate_arx(arx, case.inputs)
    )


def test_every_denominator_of_the_result_is_stable(noisy_fit):
    """The output-error search only ever accepts models with every pole inside the unit circle."""
    _, _, result = noisy_fit
    assert result.parameters.stable()
    for f in result.parameters.f:
        assert np.max(np.abs(np.roots(f))) < 1.0


def test_separate_denominators_are_recovered_on_clean_data():
    """Two inputs with different first-order dynamics: OE finds each input's own pole and gain."""
    tfs = [
        (np.array([0.0, 2.0 * (1 - np.exp(-TS / 1200.0))]), np.array([1.0, -np.exp(-TS / 1200.0)])),
        (
            np.array([0.0, -1.0 * (1 - np.exp(-TS / 6000.0))]),
            np.array([1.0, -np.exp(-TS / 6000.0)]),
        ),
    ]
    case = make_case(tfs, hours=40, sample_time_s=TS, seed=8)
    arx = fit_arx(case.y, case.inputs, 1, [1, 1], [1, 1])  # one shared pole: a compromise
    result = fit_oe(case.y, case.inputs, oe_from_arx(arx.a, arx.b, arx.nk, [1, 1]))
    for f, (b_true, a_true), b in zip(result.parameters.f, tfs, result.parameters.b, strict=True):
        assert_allclose(f, a_true, rtol=1e-7)
        assert_allclose(b, b_true[1:], rtol=1e-5)


def test_oe_from_arx_needs_matching_orders():
    """An ARX start of order 2 cannot seed first-order OE denominators."""
    with pytest.raises(ModelError, match="na equal"):
        oe_from_arx(np.array([1.0, -1.5, 0.56]), [np.ones(1)], [1], [1])


def test_unstable_start_is_refused():
    """A starting model with a pole outside the unit circle is an error, not a silent flip."""
    start = OeParameters((np.ones(1),), (np.array([1.0, -1.01]),), (1,))
    y = np.zeros(100)
    with pytest.raises(ModelError, match="unstable"):
        fit_oe(y, np.ones((100, 1)), start)


def test_simulation_starts_at_rest_with_the_delay():
    """``simulate_oe`` is zero until the input delay has passed and then follows B/F."""
    parameters = OeParameters((np.array([0.5]),), (np.array([1.0, -0.5]),), (2,))
    u = np.ones((6, 1))
    assert_allclose(simulate_oe(parameters, u), [0.0, 0.0, 0.5, 0.75, 0.875, 0.9375])


def test_admissible_denominators_are_stable_zoh_equivalents():
    """Poles inside the unit circle off the non-positive real axis are admissible; others are not."""
    assert admissible(np.poly([0.999, 0.5]))
    assert admissible(np.real(np.poly([0.9 + 0.1j, 0.9 - 0.1j])))
    assert not admissible(np.poly([0.999, -0.3]))
    assert not admissible(np.poly([0.999, 0.0]))
    assert not admissible(np.poly([1.0001]))


def test_a_start_pole_on_the_negative_axis_is_moved_and_the_result_is_admissible():
    """A start with a negative real pole still gives an admissible fit of a first-order system."""
    pole = np.exp(-TS / 1800.0)
    case = make_case([(np.array([0.0, 1.0 - pole]), np.array([1.0, -pole]))], hours=20, seed=9)
    start = OeParameters((np.ones(2),), (np.poly([0.99, -0.5]),), (1,))
    result = fit_oe(case.y, case.inputs, start)
    (f,) = result.parameters.f
    assert admissible(f)
    assert fit_percent(case.y, simulate_oe(result.parameters, case.inputs)) > 99.99
