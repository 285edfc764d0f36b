"""Position multipliers (Pahk 2002 ``m1(T) * P + m2(T)``): running them, and identifying slope channels."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.signal
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.testing import assert_allclose

from compd.errors import ModelError
from compd.model import (
    Gate,
    GateTarget,
    InputSpec,
    Model,
    Output,
    Position,
    SubModel,
    TickRunner,
    compile_model,
    simulate,
)
from compd.model.identify import identify
from compd.model.position import (
    channel_scales,
    check_position,
    refine_scaled,
    refit_numerators,
)
from tests.model.conftest import first_order
from tests.model.test_run import stable_tfs


@st.composite
def positioned_models(draw: st.DrawFn) -> Model:
    """1-2 outputs of 1-3 sub-models on s0/s1, each with or without a gate and a position."""
    outputs = []
    for out_i in range(draw(st.integers(1, 2))):
        subs = []
        for sub_i in range(draw(st.integers(1, 3))):
            gate = draw(
                st.one_of(
                    st.none(),
                    st.builds(Gate, st.just("s2"), st.floats(-0.5, 0.5), st.booleans(),
                              st.sampled_from(list(GateTarget))),
                )
            )  # fmt: skip
            position = draw(
                st.one_of(
                    st.none(),
                    st.builds(Position, st.sampled_from(["x_mm", "z_mm"]), st.floats(-50, 50)),
                )
            )
            subs.append(
                SubModel(
                    f"sub{sub_i}",
                    "e",
                    InputSpec(draw(st.sampled_from(["s0", "s1"])), None, draw(st.floats(-5, 5))),
                    draw(stable_tfs()),
                    draw(st.floats(0.0, 2.0)),
                    gate,
                    position=position,
                )
            )
        outputs.append(Output(f"out{out_i}", tuple(subs)))
    return Model("positioned", 1.0, tuple(outputs))


@settings(max_examples=40, deadline=None)
@given(model=positioned_models(), seed=st.integers(0, 2**32 - 1))
def test_step_and_simulate_agree_with_position_multipliers(model: Model, seed: int) -> None:
    """With position multipliers, per-tick step and vectorised simulate still agree to 1e-9."""
    compiled = compile_model(model)
    rng = np.random.default_rng(seed)
    signals = rng.normal(size=(300, len(compiled.signals))).cumsum(axis=0) * 0.3
    for name in ("x_mm", "z_mm"):
        if name in compiled.signals:
            # positions dwell at a few stops, as an axis between measurements does
            stops = rng.choice([-200.0, 0.0, 350.0, 700.0], size=30)
            signals[:, compiled.signals.index(name)] = np.repeat(stops, 10)
    state = compiled.rest_state(signals[0])
    result = simulate(compiled, signals, state)
    runner = TickRunner(compiled, state)
    stepped = np.array([runner.step(row) for row in signals])
    scale = max(1.0, float(np.max(np.abs(result.outputs))))
    assert_allclose(stepped, result.outputs, rtol=1e-9, atol=1e-9 * scale)
    assert_allclose(runner.state.z, result.final_state.z, rtol=1e-9, atol=1e-9 * scale)


def test_a_position_scales_the_contribution_not_the_state() -> None:
    """The output is TF(u) times (P - P_ref), while the TF state and steady state ignore P."""
    tf = first_order(2.0, 0.9)
    plain = SubModel("m2", "offset", InputSpec("T_degC", reference=0.0), tf)
    sloped = SubModel("m1", "slope", InputSpec("T_degC", reference=0.0), tf,
                      position=Position("X_mm", 100.0))  # fmt: skip
    model = Model("axis", 1.0, (Output("disp_x_um", (plain, sloped)),))
    compiled = compile_model(model)
    assert compiled.signals == ("T_degC", "X_mm")
    n = 200
    u = np.sin(np.arange(n) / 9.0) + 1.0
    x_mm = np.repeat([0.0, 300.0, 600.0, 100.0], n // 4)
    result = simulate(compiled, np.column_stack([u, x_mm]), compiled.rest_state([0.0, 0.0]))
    response = scipy.signal.lfilter(tf.b, tf.a, u)
    assert_allclose(result.outputs[:, 0], response * (1.0 + (x_mm - 100.0)), rtol=1e-12)
    assert_allclose(result.contributions[x_mm == 100.0, 1], 0.0, atol=1e-15)
    at_0 = compiled.steady_state({"T_degC": 3.0, "X_mm": 0.0})
    at_600 = compiled.steady_state({"T_degC": 3.0, "X_mm": 600.0})
    assert_allclose(at_0.z, at_600.z)


def test_a_record_at_one_position_is_refused() -> None:
    """A slope cannot be identified from one measurement position: the error says to measure at two or more."""
    with pytest.raises(ModelError, match="two or more positions"):
        check_position(np.full(100, 250.0), 100)
    with pytest.raises(ModelError, match="NaN"):
        check_position(np.r_[np.nan, np.ones(99)], 100)


def test_refit_numerators_recovers_a_slope_model_with_known_denominators() -> None:
    """Given the true poles, the least-squares numerator step returns the true numerators exactly."""
    rng = np.random.default_rng(3)
    n = 600
    u = np.column_stack([rng.normal(size=n).cumsum(), rng.normal(size=n).cumsum()])
    u = np.column_stack([u[:, 0], u[:, 1], u[:, 0]])
    true = [first_order(1.5, 0.95), first_order(-0.7, 0.8), first_order(0.02, 0.97)]
    position_mm = np.repeat(rng.uniform(0, 800, size=n // 20), 20)
    scales = channel_scales([False, False, True], position_mm)
    y = sum(scales[:, i] * scipy.signal.lfilter(tf.b, tf.a, u[:, i]) for i, tf in enumerate(true))
    start = [first_order(1.0, 0.95), first_order(1.0, 0.8), first_order(1.0, 0.97)]
    refitted = refit_numerators(np.asarray(y), u, start, scales)
    for got, want in zip(refitted, true, strict=True):
        assert_allclose(got.num, want.num, rtol=1e-8)
        assert got.den == want.den and got.nk == want.nk


def test_identify_with_a_position_fits_the_offset_and_the_slope() -> None:
    """On noiseless data made of an offset TF and a slope TF times the position, the fit is near perfect."""
    rng = np.random.default_rng(7)
    n = 1500
    t_degc = np.cumsum(rng.normal(0, 0.05, size=n))
    position_mm = np.repeat(rng.choice([50.0, 250.0, 450.0, 650.0], size=n // 30), 30)
    offset, slope = first_order(2.0, 0.9), first_order(0.01, 0.9)
    y = scipy.signal.lfilter(offset.b, offset.a, t_degc) + position_mm * scipy.signal.lfilter(
        slope.b, slope.a, t_degc
    )
    result = identify(y, {"T_degC": t_degc}, sample_time_s=10.0, method="arx", order=1,
                      position=position_mm)  # fmt: skip
    assert [(c.input_name, c.sloped) for c in result.channels] == [
        ("T_degC", False),
        ("T_degC", True),
    ]
    assert result.fit_percent > 99.0
    assert result.channels[1].tf.static_gain() == pytest.approx(0.01, rel=0.02)
    with pytest.raises(ModelError, match="distinct"):
        identify(y, {"T_degC": t_degc}, sample_time_s=10.0, position=np.full(n, 300.0))


def test_refine_scaled_moves_biased_poles_to_the_true_ones() -> None:
    """Started from wrong poles, the joint refinement finds the true slope TF when the axis moves often."""
    rng = np.random.default_rng(11)
    n = 1200
    u = np.cumsum(rng.normal(0, 0.1, size=n))[:, None].repeat(2, axis=1)
    position_mm = np.repeat(rng.choice([100.0, 400.0, 700.0], size=n // 8), 8)
    true = [first_order(1.0, 0.9), first_order(0.004, 0.95)]
    scales = channel_scales([False, True], position_mm)
    y = sum(scales[:, i] * scipy.signal.lfilter(tf.b, tf.a, u[:, i]) for i, tf in enumerate(true))
    start = [first_order(0.8, 0.8), first_order(0.003, 0.8)]
    refined = refine_scaled(np.asarray(y), u, start, scales, max_evaluations=200)
    for got, want in zip(refined, true, strict=True):
        assert_allclose(got.poles(), want.poles(), rtol=1e-6)
        assert got.static_gain() == pytest.approx(want.static_gain(), rel=1e-6)
