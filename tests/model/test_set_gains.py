"""TickRunner.set_gains: named gains change the outputs at once and never the filter states."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from numpy.testing import assert_allclose

from compd.errors import ModelError
from compd.model import (
    CompiledModel,
    Gate,
    GateTarget,
    InputSpec,
    Model,
    Output,
    SubModel,
    compile_model,
)
from compd.model.run import TickRunner
from compd.model.structure import Position
from tests.model.conftest import first_order


def scheduled_model(g1: float = 1.0, g2: float = 1.0) -> Model:
    """Two outputs; ``g1`` shared by one sub-model of each, ``g2`` gated, one slope term, one fixed."""

    def sub(name: str, signal: str, pole: float, **extra: object) -> SubModel:
        return SubModel(
            name, name, InputSpec(signal, reference=20.0), first_order(2.0, pole), **extra
        )  # type: ignore[arg-type]

    z = Output(
        "disp_z_um",
        (
            sub("cooling", "T_spindle_degC", 0.99, gain=g1, gain_name="g1"),
            sub(
                "heating",
                "T_spindle_degC",
                0.95,
                gain=g2,
                gain_name="g2",
                gate=Gate("speed_rpm", 0.0, True, GateTarget.INPUT),
            ),
            sub("ambient", "T_room_degC", 0.999, gain=0.7),
        ),
    )
    y = Output(
        "disp_y_um",
        (
            sub("cooling", "T_spindle_degC", 0.98, gain=g1, gain_name="g1"),
            sub("screw", "T_room_degC", 0.9, position=Position("x_mm", 100.0)),
        ),
    )
    return Model("scheduled", 1.0, (z, y))


def signals(compiled: CompiledModel, n: int) -> np.ndarray:
    """``n`` ticks of heating and cooling, spindle on and off, the axis moving; in model order."""
    rng = np.random.default_rng(3)
    t = np.arange(n, dtype=float)
    columns = {
        "T_spindle_degC": 20.0 + 8.0 * np.sin(t / 40.0) + rng.normal(0, 0.05, n),
        "T_room_degC": 20.0 + 0.5 * np.sin(t / 90.0),
        "speed_rpm": np.where((t // 25) % 2 == 0, 3000.0, 0.0),
        "x_mm": 100.0 + 300.0 * np.sin(t / 60.0),
    }
    return np.column_stack([columns[name] for name in compiled.signals])


def test_set_gains_equals_a_model_built_with_those_gains_from_then_on() -> None:
    """After set_gains at tick k, outputs equal a model with those gains all along; states stay equal."""
    changed = compile_model(scheduled_model())
    target = compile_model(scheduled_model(g1=0.6, g2=1.3))
    data = signals(changed, 300)
    a = TickRunner(changed, changed.steady_state(data[0]))
    b = TickRunner(target, target.steady_state(data[0]))
    for k, row in enumerate(data):
        if k == 120:
            a.set_gains({"g1": 0.6, "g2": 1.3})
        out_a, out_b = a.step(row), b.step(row)
        assert_allclose(a.state.z, b.state.z, rtol=0, atol=1e-12)
        if k >= 120:
            assert_allclose(out_a, out_b, rtol=1e-12, atol=1e-12)
            assert_allclose(a.contributions, b.contributions, rtol=1e-12, atol=1e-12)
    assert a.gains == {"g1": 0.6, "g2": 1.3}


def test_names_not_given_keep_their_value_and_fixed_gains_never_change() -> None:
    """Setting g2 alone leaves g1 (both its sub-models) and the unnamed fixed gains as they were."""
    compiled = compile_model(scheduled_model(g1=0.8))
    runner = TickRunner(compiled, compiled.rest_state(signals(compiled, 1)[0]))
    assert runner.gains == {"g1": 0.8, "g2": 1.0}
    runner.set_gains({"g2": 0.5})
    assert runner.gains == {"g1": 0.8, "g2": 0.5}
    expected = compile_model(scheduled_model(g1=0.8, g2=0.5)).output_matrix * np.array(
        [0.8, 0.5, 0.7, 0.8, 1.0]
    )
    assert_allclose(compiled.output_matrix * runner.submodel_gains, expected)


def test_an_unknown_or_non_finite_gain_is_refused_and_nothing_changes() -> None:
    """A name the model does not give, or a NaN, raises ModelError naming it; no gain moves."""
    compiled = compile_model(scheduled_model())
    runner = TickRunner(compiled, compiled.rest_state(signals(compiled, 1)[0]))
    with pytest.raises(ModelError, match=r"no gain named 'g3'.*\['g1', 'g2'\]"):
        runner.set_gains({"g1": 0.5, "g3": 1.0})
    with pytest.raises(ModelError, match="'g2' must be finite"):
        runner.set_gains({"g1": 0.5, "g2": float("nan")})
    assert runner.gains == {"g1": 1.0, "g2": 1.0}
    plain = dataclasses.replace(scheduled_model(), outputs=scheduled_model().outputs[1:])
    bare = compile_model(
        dataclasses.replace(
            plain,
            outputs=(
                Output(
                    "disp_y_um",
                    tuple(
                        dataclasses.replace(s, gain_name=None) for s in plain.outputs[0].submodels
                    ),
                ),
            ),
        )
    )
    with pytest.raises(ModelError, match="no sub-model has a gain_name"):
        TickRunner(bare, bare.rest_state(signals(bare, 1)[0])).set_gains({"g1": 1.0})
