"""Compiled models: flat arrays, initial states, gates, superposition and serialisable state."""

import json

import numpy as np
import pytest
from numpy.testing import assert_allclose

from compd.errors import ModelError
from compd.model import (
    ContinuousTF,
    GateTarget,
    InputSpec,
    Model,
    ModelState,
    Output,
    SubModel,
    TickRunner,
    compile_model,
)
from tests.model.conftest import first_order, gate_on, single


def test_steady_state_start_has_no_transient() -> None:
    """Started at steady state for a constant input, the output sits at gain * input from the first tick."""
    compiled = compile_model(single(first_order(2.5, 0.999), reference=20.0))
    runner = TickRunner(compiled, compiled.steady_state([24.0]))
    outputs = [runner.step([24.0])[0] for _ in range(500)]
    assert_allclose(outputs, 2.5 * 4.0, rtol=1e-12)


def test_rest_start_begins_at_zero_and_rises() -> None:
    """Started at rest, the output starts from zero and approaches the static gain."""
    compiled = compile_model(single(first_order(2.0, 0.9), reference=0.0))
    runner = TickRunner(compiled, compiled.rest_state([1.0]))
    outputs = np.array([runner.step([1.0])[0] for _ in range(200)])
    assert outputs[0] == 0.0  # nk = 1: the input reaches the output one sample later
    assert outputs[-1] == pytest.approx(2.0, rel=1e-6)
    assert np.all(np.diff(outputs) >= 0)


def test_reference_at_start_makes_the_input_a_change_from_the_first_value() -> None:
    """With reference 'start', a machine that is warm at start shows no offset until something changes."""
    compiled = compile_model(single(first_order(3.0, 0.5), reference=None))
    state = compiled.steady_state([31.7])
    assert_allclose(state.reference, [31.7])
    runner = TickRunner(compiled, state)
    assert runner.step([31.7])[0] == 0.0
    for _ in range(100):
        last = runner.step([32.7])[0]
    assert last == pytest.approx(3.0)


def test_output_gate_switches_the_contribution_instantly() -> None:
    """Post-process 2024 eq. 5: an output gate drops the contribution to zero the tick the spindle stops."""
    tf = first_order(1.0, 0.99)
    sub = SubModel("heat", "spindle", InputSpec("T_degC", reference=0.0), tf, 1.0, gate_on())
    compiled = compile_model(Model("m", 1.0, (Output("disp_z_um", (sub,)),)))
    runner = TickRunner(compiled, compiled.steady_state({"T_degC": 5.0, "speed_rpm": 4000.0}))
    assert runner.step({"T_degC": 5.0, "speed_rpm": 4000.0})[0] == pytest.approx(5.0)
    assert runner.step({"T_degC": 5.0, "speed_rpm": 0.0})[0] == 0.0
    assert runner.step({"T_degC": 5.0, "speed_rpm": 10.0})[0] == pytest.approx(5.0)


def test_input_gate_lets_the_contribution_decay_with_the_tf_dynamics() -> None:
    """An input gate zeroes the TF's input, so the contribution decays at the TF's own pole."""
    tf = first_order(1.0, 0.99)
    sub = SubModel(
        "heat",
        "spindle",
        InputSpec("T_degC", reference=0.0),
        tf,
        1.0,
        gate_on(target=GateTarget.INPUT),
    )
    compiled = compile_model(Model("m", 1.0, (Output("disp_z_um", (sub,)),)))
    runner = TickRunner(compiled, compiled.steady_state({"T_degC": 5.0, "speed_rpm": 4000.0}))
    stopped = [runner.step({"T_degC": 5.0, "speed_rpm": 0.0})[0] for _ in range(3)]
    assert_allclose(stopped, [5.0, 5.0 * 0.99, 5.0 * 0.99**2], rtol=1e-12)


def test_below_gate_is_active_under_the_threshold() -> None:
    """A gate with above=False is open while the signal is below its threshold (e.g. door closed)."""
    from compd.model import Gate

    sub = SubModel(
        "s",
        "e",
        InputSpec("T_degC", reference=0.0),
        first_order(1.0, 0.5),
        1.0,
        Gate("door", 0.5, above=False),
    )
    compiled = compile_model(Model("m", 1.0, (Output("y", (sub,)),)))
    runner = TickRunner(compiled, compiled.steady_state({"T_degC": 2.0, "door": 0.0}))
    assert runner.step({"T_degC": 2.0, "door": 0.0})[0] == pytest.approx(2.0)
    assert runner.step({"T_degC": 2.0, "door": 1.0})[0] == 0.0


def test_outputs_are_the_sum_of_their_gained_sub_models() -> None:
    """Superposition (Horejs 2015): each output sums its own sub-models' contributions times their gains."""
    subs_z = (
        SubModel("a", "ambient", InputSpec("T_amb", reference=0.0), first_order(1.0, 0.9), 2.0),
        SubModel("b", "spindle", InputSpec("T_sp", "T_amb", 0.0), first_order(0.5, 0.8), 1.0),
    )
    subs_y = (
        SubModel("c", "spindle", InputSpec("T_sp", reference=0.0), first_order(3.0, 0.7), 0.5),
    )
    compiled = compile_model(Model("m", 1.0, (Output("z", subs_z), Output("y", subs_y))))
    assert compiled.signals == ("T_amb", "T_sp")
    runner = TickRunner(compiled, compiled.steady_state([1.0, 3.0]))
    z, y = runner.step([1.0, 3.0])
    assert z == pytest.approx(2.0 * 1.0 + 0.5 * (3.0 - 1.0))
    assert y == pytest.approx(0.5 * 3.0 * 3.0)
    assert_allclose(runner.contributions, [2.0, 1.0, 4.5])


def test_state_round_trips_through_json_and_continues_identically() -> None:
    """A state saved as JSON mid-run and restored continues exactly as if never interrupted."""
    compiled = compile_model(single(ContinuousTF.from_coefficients([1.0], [1.0, 300.0, 2000.0])))
    runner = TickRunner(compiled, compiled.rest_state([0.0]))
    for k in range(50):
        runner.step([np.sin(k / 5)])
    restored = TickRunner(
        compiled, ModelState.from_dict(json.loads(json.dumps(runner.state.to_dict())))
    )
    for k in range(50, 100):
        assert restored.step([np.sin(k / 5)])[0] == runner.step([np.sin(k / 5)])[0]


def test_a_state_from_another_model_is_refused() -> None:
    """Restoring a state of the wrong shape is refused rather than misapplied."""
    small = compile_model(single(first_order(1.0, 0.5)))
    large = compile_model(single(ContinuousTF.from_coefficients([1.0], [1.0, 3.0, 2.0])))
    with pytest.raises(ModelError, match="different model"):
        TickRunner(large, small.rest_state([0.0]))


def test_non_finite_input_is_refused_and_leaves_the_state_unchanged() -> None:
    """A NaN reading raises and the model state is exactly what it was before."""
    compiled = compile_model(single(first_order(1.0, 0.9)))
    runner = TickRunner(compiled, compiled.steady_state([2.0]))
    before = runner.state
    with pytest.raises(ModelError, match="non-finite"):
        runner.step([float("nan")])
    assert_allclose(runner.state.z, before.z)
    assert runner.step([2.0])[0] == pytest.approx(2.0)


def test_compile_error_names_the_sub_model() -> None:
    """An unstable sub-model is refused with its place in the model."""
    bad = SubModel(
        "bad",
        "e",
        InputSpec("T", reference=0.0),
        ContinuousTF.from_coefficients([1.0], [-1.0, 1.0]),
    )
    good = SubModel("good", "e", InputSpec("T", reference=0.0), first_order(1.0, 0.5))
    with pytest.raises(ModelError, match=r"outputs\.disp_z_um\.submodels\[1\] \(bad\): unstable"):
        compile_model(Model("m", 1.0, (Output("disp_z_um", (good, bad)),)))


def test_compiled_arrays_are_padded_to_a_common_length() -> None:
    """Sub-models of different orders share one (S, L) layout with a0 == 1."""
    compiled = compile_model(
        Model(
            "m",
            1.0,
            (
                Output(
                    "z",
                    (
                        SubModel("a", "e", InputSpec("T"), first_order(1.0, 0.5, nk=4)),
                        SubModel(
                            "b",
                            "e",
                            InputSpec("T"),
                            ContinuousTF.from_coefficients([1.0], [1.0, 3.0, 2.0]),
                        ),
                    ),
                ),
            ),
        )
    )
    assert compiled.b.shape == compiled.a.shape == (2, 5)
    assert_allclose(compiled.a[:, 0], 1.0)
    assert compiled.n_states == 4
