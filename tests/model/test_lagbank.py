"""The lag bank: stable first-order lags at fixed time constants, weights chosen by cross-validation."""

from __future__ import annotations

import numpy as np
import scipy.signal
from numpy.testing import assert_allclose

from compd.model.compiled import compile_model
from compd.model.crossval import blocked_folds, cycle_folds
from compd.model.lagbank import fit_lag_bank, lag_features, lag_tf, regression_cv
from compd.model.run import simulate
from compd.model.structure import InputSpec, Model, Output, SubModel

DT_S = 15.0


def _heat_cycles(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A spindle on/off programme and three temperatures that follow it with different lags."""
    on = ((np.arange(n) * DT_S) // (4 * 3600) % 2 == 0).astype(float) * rng.uniform(0.5, 1.5)
    speed = np.repeat(rng.uniform(0.5, 1.5, n // 960 + 1), 960)[:n] * on
    taus = (600.0, 2400.0, 7200.0)
    temps = np.column_stack(
        [scipy.signal.lfilter(*_zoh(tau), 3.0 * speed) for tau in taus]
    ) + rng.normal(0, 0.01, (n, 3))
    return speed, temps


def _zoh(tau_s: float) -> tuple[list[float], list[float]]:
    a = np.exp(-DT_S / tau_s)
    return [0.0, 1.0 - a], [1.0, -a]


def test_a_lag_is_the_zero_order_hold_of_a_first_order_tf() -> None:
    """``g / (tau s + 1)`` held at 15 s is what scipy's cont2discrete gives."""
    tf = lag_tf(2.5, 1200.0, DT_S)
    num, den, _ = scipy.signal.cont2discrete(([2.5], [1200.0, 1.0]), DT_S, method="zoh")
    assert_allclose(
        tf.b, np.trim_zeros(num.ravel(), "b") if num.ravel()[0] == 0 else num.ravel(), atol=1e-15
    )
    assert_allclose(tf.a, den, rtol=1e-12)
    assert tf.static_gain() == 2.5 and lag_tf(-1.0, 0.0, DT_S).static_gain() == -1.0


def test_features_are_the_lags_run_from_rest() -> None:
    """Each feature column is its lag's TF run over the input from rest."""
    u = np.cumsum(np.random.default_rng(0).normal(size=(300, 2)), axis=0)
    x = lag_features(u, (0.0, 900.0), DT_S)
    tf = lag_tf(1.0, 900.0, DT_S)
    assert_allclose(x[:, :2], u)
    assert_allclose(x[:, 3], scipy.signal.lfilter(tf.b, tf.a, u[:, 1]))


def test_a_system_inside_the_bank_is_recovered_on_held_out_cycles() -> None:
    """A displacement made of lags on the grid is predicted on cycles the fit never saw."""
    rng = np.random.default_rng(1)
    n = 8 * 960
    speed, temps = _heat_cycles(n, rng)
    taus = (0.0, 1200.0, 3600.0)
    truth = lag_features(temps, taus, DT_S) @ rng.normal(0, 2.0, 9)
    fit = fit_lag_bank(
        truth, temps, sample_time_s=DT_S, folds=cycle_folds(speed), time_constants_s=taus
    )
    assert fit.cv_fit_percent is not None and fit.cv_fit_percent > 95.0
    assert fit.fit_percent > 97.0


def test_duplicated_sensors_share_their_weight_instead_of_cancelling() -> None:
    """Two near-identical sensors get similar, moderate gains, not a huge +/- pair."""
    rng = np.random.default_rng(2)
    n = 8 * 960
    speed, temps = _heat_cycles(n, rng)
    twin = temps[:, [0]] + 0.2 + rng.normal(0, 0.01, (n, 1))  # the same node, a Pt100 offset
    u = np.hstack([temps, twin - twin[0]])
    y = 4.0 * temps[:, 0] + rng.normal(0, 0.05, n)
    fit = fit_lag_bank(y, u, sample_time_s=DT_S, folds=cycle_folds(speed))
    static = fit.gains.sum(axis=1)  # um per K at steady state, per input
    assert abs(static[0] - static[3]) < 0.25
    assert np.max(np.abs(fit.gains)) < 10.0
    assert fit.cv_fit_percent is not None and fit.cv_fit_percent > 90.0


def test_the_exported_tfs_run_in_compd_as_fitted() -> None:
    """Sub-models built from the gains reproduce the fitted prediction when compd simulates them."""
    rng = np.random.default_rng(3)
    n = 4 * 960
    _, temps = _heat_cycles(n, rng)
    temps -= temps[0]  # changes from the record's start, as compd runs a model
    y = lag_features(temps, (0.0, 3600.0), DT_S) @ np.array([1.0, -0.5, 0.2, 2.0, 1.0, -1.0])
    fit = fit_lag_bank(y, temps, sample_time_s=DT_S, folds=blocked_folds(n))
    names = ["a", "b", "c"]
    subs = tuple(
        SubModel(f"{name}_{j}", "lag", InputSpec(name), tf)
        for name, tfs in zip(names, fit.channel_tfs(DT_S), strict=True)
        for j, tf in enumerate(tfs)
    )
    compiled = compile_model(Model("m", DT_S, (Output("y", subs),)))
    signals = temps + rng.normal(0, 1.0, 3)  # absolute values: compd references them to the start
    result = simulate(compiled, signals, compiled.rest_state(signals[0]))
    assert_allclose(result.output(compiled, "y"), fit.predicted_um, atol=1e-8)


def test_the_regression_baseline_is_scored_the_same_way() -> None:
    """The static regression's cross-validated fit is below its calibration fit on lagging data."""
    rng = np.random.default_rng(4)
    n = 8 * 960
    speed, temps = _heat_cycles(n, rng)
    y = lag_features(temps[:, :1], (3600.0,), DT_S)[:, 0] * 5.0
    gains, cv = regression_cv(y, temps, cycle_folds(speed))
    calibration = 100 * (1 - np.linalg.norm(y - temps @ gains) / np.linalg.norm(y - y.mean()))
    assert cv < calibration


def test_lag_names_carry_their_input_so_readers_can_group_them() -> None:
    """``T5_lag_3600s`` and ``T5_gain`` give back ``T5``; an ordinary sub-model name gives nothing."""
    from compd.model.lagbank import lag_name, lag_prefix

    assert [lag_name("T5", t) for t in (0.0, 3600.0)] == ["T5_gain", "T5_lag_3600s"]
    assert lag_prefix("T5_lag_3600s") == lag_prefix("T5_gain") == "T5"
    assert lag_prefix("spindle_power_kw_effect_lag_300s") == "spindle_power_kw_effect"
    assert lag_prefix("T_spindle_degC") is None
