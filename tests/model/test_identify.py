"""The identification entry point: methods, automatic orders, phase gate, argument checks."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.signal
from numpy.testing import assert_allclose

from compd.errors import ModelError
from compd.model.identify import identify, simulate_channels
from compd.model.metrics import fit_percent
from tests.model.thermal_cases import held_levels, make_case, thermal_second_order

TS = 10.0


@pytest.fixture(scope="module")
def arx_case():
    """Two inputs through one second-order denominator with nk = 1, noise-free, 30 h at 10 s."""
    a = np.poly(np.exp(-TS / np.array([1200.0, 7200.0])))
    tfs = [(np.array([0.0, 2.0e-3, -1.2e-3]), a), (np.array([0.0, -0.7e-3, 0.9e-3]), a)]
    return make_case(tfs, hours=30, sample_time_s=TS, seed=11)


@pytest.fixture(scope="module")
def oe_case():
    """Two inputs with their own second-order TFs, 1 % output noise, 60 h at 10 s."""
    tfs = [
        thermal_second_order((1200.0, 5400.0), 2.0, 0.3, TS),
        thermal_second_order((2400.0, 7200.0), -1.5, 0.6, TS),
    ]
    return make_case(tfs, hours=60, sample_time_s=TS, noise_fraction=0.01, seed=12)


def test_auto_orders_pick_the_true_arx_orders_on_clean_data(arx_case):
    """On noise-free data the validation search chooses na = 2, nb = 2, nk = 1 for every input."""
    result = identify(arx_case.y, arx_case.named(), sample_time_s=TS, method="arx")
    assert result.orders.na == 2
    assert result.orders.nb == (2, 2)
    assert result.orders.nk == (1, 1)
    assert result.validation_fit_percent is not None and result.validation_fit_percent > 99.99
    for channel, b in zip(result.channels, arx_case.b, strict=True):
        assert_allclose(channel.tf.b, b, rtol=1e-5, atol=1e-12)


def test_fit_percent_is_the_free_run_simulation_fit(arx_case):
    """The reported fit is Horejs 2015 eq. 2 of one lfilter per channel from rest, as compare runs it."""
    result = identify(arx_case.y, arx_case.named(), sample_time_s=TS, method="arx", order=1)
    simulated = sum(
        scipy.signal.lfilter(c.tf.b, c.tf.a, arx_case.inputs[:, i])
        for i, c in enumerate(result.channels)
    )
    assert_allclose(result.simulated_um, simulated, rtol=1e-12, atol=1e-12)
    assert result.fit_percent == pytest.approx(fit_percent(arx_case.y, simulated), abs=1e-12)
    assert result.validation_fit_percent is None


def test_oe_reaches_the_true_models_fit_where_arx_does_not(oe_case):
    """With output noise OE at a fixed order fits within 0.05 points of the truth; ARX falls short."""
    true_fit = fit_percent(oe_case.y, oe_case.y_true)
    oe = identify(oe_case.y, oe_case.named(), sample_time_s=TS, method="oe", order=2)
    arx = identify(oe_case.y, oe_case.named(), sample_time_s=TS, method="arx", order=2)
    assert oe.fit_percent > true_fit - 0.05
    assert arx.fit_percent < true_fit - 1.0
    assert all(c.tf.order == 2 and c.tf.nk == 1 for c in oe.channels)


def test_oe_auto_chooses_an_order_and_reports_its_validation_fit(oe_case):
    """Automatic OE orders give a stable model near the true fit, with a held-back validation fit."""
    true_fit = fit_percent(oe_case.y, oe_case.y_true)
    stages: list[str] = []
    result = identify(
        oe_case.y,
        oe_case.named(),
        sample_time_s=TS,
        method="oe",
        progress=lambda stage, fraction: stages.append(stage),
    )
    assert result.fit_percent > true_fit - 0.2
    assert result.validation_fit_percent is not None and result.validation_fit_percent > 95.0
    assert "OE order 1 (first two thirds)" in stages
    for channel in result.channels:
        channel.tf.check_stable()


def test_mlr_equals_numpy_lstsq_without_intercept(oe_case):
    """MLR's gains are np.linalg.lstsq of y on the inputs (no intercept), as static TFs."""
    result = identify(oe_case.y, oe_case.named(), sample_time_s=TS, method="mlr")
    expected = np.linalg.lstsq(oe_case.inputs, oe_case.y, rcond=None)[0]
    assert_allclose([c.tf.static_gain() for c in result.channels], expected, rtol=1e-10)
    assert all(c.tf.order == 0 and c.tf.nk == 0 for c in result.channels)
    assert result.fit_percent == pytest.approx(
        fit_percent(oe_case.y, oe_case.inputs @ expected), abs=1e-9
    )


def test_phase_gate_recovers_a_gated_system():
    """A cooling TF always on plus a heating-difference TF on the gated input are both recovered."""
    rng = np.random.default_rng(13)
    n = int(40 * 3600 / TS)
    u = held_levels(rng, n, TS)
    gate = np.zeros(n, dtype=bool)
    t = 0
    while t < n:
        on = int(rng.integers(1800, 3 * 3600) / TS)
        gate[t : t + on] = True
        t += on + int(rng.integers(1800, 3 * 3600) / TS)
    cool_b, cool_a = thermal_second_order((1800.0, 5400.0), 1.2, 0.5, TS)
    heat_b, heat_a = thermal_second_order((900.0, 2700.0), 0.8, 0.4, TS)
    y = scipy.signal.lfilter(cool_b, cool_a, u) + scipy.signal.lfilter(heat_b, heat_a, u * gate)
    result = identify(y, {"T_degC": u}, sample_time_s=TS, method="oe", order=2, gate=gate)
    cooling, heating = result.channels
    assert (cooling.gated, heating.gated) == (False, True)
    assert cooling.input_name == heating.input_name == "T_degC"
    assert result.fit_percent > 99.9
    assert cooling.tf.static_gain() == pytest.approx(1.2, rel=1e-3)
    assert heating.tf.static_gain() == pytest.approx(0.8, rel=1e-3)
    assert_allclose(
        simulate_channels([cooling.tf, heating.tf], np.column_stack([u, u * gate])), y, atol=1e-3
    )


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"inputs": {}}, "no inputs"),
        ({"inputs": {"flat": np.zeros(200)}}, "never changes"),
        ({"order": 0}, "order must be"),
        ({"order": 4}, "order must be"),
        ({"method": "nn"}, "unknown method"),
        ({"gate": np.ones(200, dtype=bool)}, "always > 0"),
        ({"gate": np.zeros(200, dtype=bool)}, "never > 0"),
        ({"inputs": {"short": np.ones(10)}}, "shape"),
    ],
)
def test_bad_arguments_are_errors_that_say_what_to_do(kwargs, message):
    """Empty or constant inputs, orders outside 1..3, unknown methods and a one-phase gate are refused."""
    rng = np.random.default_rng(14)
    arguments = {
        "inputs": {"u": rng.normal(size=200).cumsum()},
        "sample_time_s": 1.0,
    } | kwargs
    with pytest.raises(ModelError, match=message):
        identify(rng.normal(size=200), **arguments)


@pytest.mark.parametrize(("method", "lags"), [("mlr", 0), ("arx", 2), ("oe", 0)])
def test_a_later_part_is_fitted_on_a_run_from_the_records_start(arx_case, method, lags):
    """With ``first_sample`` only later outputs (and ARX's lags of them) are read; fit % is on them."""
    first = arx_case.y.size // 3
    spoiled = arx_case.y.copy()
    spoiled[: first - lags] = 1e3
    results = [
        identify(y, arx_case.named(), sample_time_s=TS, method=method, order=2, first_sample=first)
        for y in (arx_case.y, spoiled)
    ]
    # Equal to the optimiser's rounding (BLAS kernels differ by the arrays' alignment):
    # spoiled outputs that were read would move the coefficients by far more.
    for clean, other in zip(results[0].channels, results[1].channels, strict=True):
        assert_allclose(other.tf.b, clean.tf.b, rtol=1e-7, atol=1e-12)
        assert_allclose(other.tf.a, clean.tf.a, rtol=1e-7)
    simulated = simulate_channels([c.tf for c in results[1].channels], arx_case.inputs)
    assert results[1].fit_percent == pytest.approx(
        fit_percent(arx_case.y[first:], simulated[first:]), rel=1e-9
    )
