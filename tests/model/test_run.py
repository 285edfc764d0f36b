"""Running models: per-tick step and vectorised simulate agree, and both equal the papers' difference equation."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.testing import assert_allclose

from compd.model import (
    DiscreteTF,
    Gate,
    GateTarget,
    InputSpec,
    Model,
    Output,
    SubModel,
    TickRunner,
    compile_model,
    simulate,
)
from tests.model.conftest import first_order, single


@st.composite
def stable_tfs(draw: st.DrawFn) -> DiscreteTF:
    """A random stable TF: real or complex-pair poles strictly inside the unit circle."""
    poles: list[complex] = []
    for _ in range(draw(st.integers(0, 2))):
        radius = draw(st.floats(0.0, 0.995))
        if draw(st.booleans()):
            poles.append(radius * draw(st.sampled_from([1.0, -1.0])))
        else:
            angle = draw(st.floats(0.05, 3.0))
            poles += [radius * np.exp(1j * angle), radius * np.exp(-1j * angle)]
    den = np.real(np.poly(poles)) if poles else np.array([1.0])
    num = draw(st.lists(st.floats(-3.0, 3.0), min_size=1, max_size=4))
    return DiscreteTF.from_coefficients(num, den, nk=draw(st.integers(0, 2)))


@st.composite
def random_models(draw: st.DrawFn) -> Model:
    """1-2 outputs of 1-3 sub-models on signals s0..s2, with random gates, gains and references."""
    outputs = []
    for out_i in range(draw(st.integers(1, 2))):
        subs = []
        for sub_i in range(draw(st.integers(1, 3))):
            signal, minus = draw(st.sampled_from(["s0", "s1"])), draw(st.sampled_from([None, "s1"]))
            gate = draw(
                st.one_of(
                    st.none(),
                    st.builds(
                        Gate,
                        st.just("s2"),
                        st.floats(-0.5, 0.5),
                        st.booleans(),
                        st.sampled_from(list(GateTarget)),
                    ),
                )
            )
            reference = draw(st.one_of(st.none(), st.floats(-5, 5)))
            subs.append(
                SubModel(
                    f"sub{sub_i}",
                    "e",
                    InputSpec(signal, minus if minus != signal else None, reference),
                    draw(stable_tfs()),
                    draw(st.floats(0.0, 2.0)),
                    gate,
                )
            )
        outputs.append(Output(f"out{out_i}", tuple(subs)))
    return Model("random", 1.0, tuple(outputs))


@settings(max_examples=60, deadline=None)
@given(model=random_models(), seed=st.integers(0, 2**32 - 1), steady=st.booleans())
def test_step_and_simulate_agree(model: Model, seed: int, steady: bool) -> None:
    """Tick-by-tick step and vectorised simulate give the same outputs (1e-9) and the same final state."""
    compiled = compile_model(model)
    rng = np.random.default_rng(seed)
    signals = rng.normal(size=(300, len(compiled.signals))).cumsum(axis=0) * 0.3
    state = compiled.steady_state(signals[0]) if steady else compiled.rest_state(signals[0])
    result = simulate(compiled, signals, state)
    runner = TickRunner(compiled, state)
    stepped = np.array([runner.step(row) for row in signals])
    scale = max(1.0, float(np.max(np.abs(result.outputs))))
    assert_allclose(stepped, result.outputs, rtol=1e-9, atol=1e-9 * scale)
    assert_allclose(runner.state.z, result.final_state.z, rtol=1e-9, atol=1e-9 * scale)
    assert_allclose(
        result.outputs, result.contributions @ compiled.output_matrix.T, atol=1e-12 * scale
    )


@settings(max_examples=40, deadline=None)
@given(model=random_models(), seed=st.integers(0, 2**32 - 1))
def test_each_contribution_stepped_is_simulates_to_the_last_bit(model: Model, seed: int) -> None:
    """The daemon's step does simulate's operations in simulate's order: contributions equal exactly."""
    compiled = compile_model(model)
    rng = np.random.default_rng(seed)
    signals = rng.normal(size=(200, len(compiled.signals))).cumsum(axis=0) * 0.3
    state = compiled.steady_state(signals[0])
    result = simulate(compiled, signals, state)
    runner = TickRunner(compiled, state)
    stepped = []
    for row in signals:
        runner.step(row)
        stepped.append(runner.contributions)
    np.testing.assert_array_equal(np.array(stepped), result.contributions)
    np.testing.assert_array_equal(runner.state.z, result.final_state.z)


def difference_equation(num: list[float], den: list[float], nk: int, u: np.ndarray) -> np.ndarray:
    """Horejs 2015 eq. 1 written out literally, from rest: an independent reference implementation."""
    y = np.zeros_like(u)
    for k in range(len(u)):
        acc = sum(num[i] * u[k - nk - i] for i in range(len(num)) if k - nk - i >= 0)
        acc -= sum(den[j] * y[k - j] for j in range(1, len(den)) if k - j >= 0)
        y[k] = acc / den[0]
    return y


def test_simulate_equals_the_papers_difference_equation() -> None:
    """A 2nd-order TF with input delay, run from rest, equals Horejs 2015 eq. 1 evaluated literally."""
    num, den, nk = [0.02, -0.011], [2.0, -3.2, 1.28], 2
    compiled = compile_model(single(DiscreteTF.from_coefficients(num, den, nk)))
    u = np.sin(np.arange(400) / 17.0) + 0.3
    result = simulate(compiled, u[:, None], compiled.rest_state([0.0]))
    assert_allclose(
        result.outputs[:, 0], difference_equation(num, den, nk, u), rtol=1e-10, atol=1e-13
    )


def test_steady_state_simulation_stays_flat_for_constant_inputs() -> None:
    """Over a whole record of constant inputs a steady-state start yields a constant output."""
    compiled = compile_model(single(first_order(4.0, 0.9995), reference=10.0))
    result = simulate(compiled, np.full((5000, 1), 12.5), compiled.steady_state([12.5]))
    assert_allclose(result.outputs[:, 0], 10.0, rtol=1e-9)
