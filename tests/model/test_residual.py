"""Swiss-lathe paper's residual model: door features, the forest as arrays, and its place in simulate and TickRunner."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose
from sklearn.ensemble import RandomForestRegressor

from compd.errors import ModelError
from compd.model.compiled import ModelState, compile_model
from compd.model.residual import DoorFeatures, Forest, ResidualModel
from compd.model.run import TickRunner, simulate
from compd.model.structure import InputSpec, Model, Output, SubModel
from compd.model.transfer import DiscreteTF
from compd.toolkit.residual import forest_from_sklearn

DT_S = 10.0


def door_record(n: int, seed: int) -> np.ndarray:
    """A 0/1 door signal with openings of 3-10 min every 10-40 min, at 10 s."""
    rng = np.random.default_rng(seed)
    values: list[float] = []
    while len(values) < n:
        values += [0.0] * int(rng.integers(60, 240)) + [1.0] * int(rng.integers(18, 60))
    return np.asarray(values[:n])


@pytest.fixture(scope="module")
def fitted() -> tuple[RandomForestRegressor, np.ndarray, DoorFeatures]:
    """A 40-tree forest fitted on a non-linear function of the door features."""
    features = DoorFeatures("door_open")
    door = door_record(3000, seed=1)
    x, _ = features.record(door, DT_S, features.initial_state(door[0]))
    y = 4.0 * np.tanh(3.0 * x[:, 1]) - 2.0 * x[:, 2] ** 2 + 0.001 * np.minimum(x[:, 3], 900.0)
    regressor = RandomForestRegressor(n_estimators=40, max_depth=12, random_state=0)
    regressor.fit(x, y + np.random.default_rng(2).normal(0, 0.1, y.size))
    return regressor, x, features


def test_forest_arrays_predict_as_sklearn(fitted) -> None:
    """The exported trees traversed with numpy equal sklearn's predict to 1e-9, per record and per sample."""
    regressor, x, _ = fitted
    forest = forest_from_sklearn(regressor)
    probe = np.vstack(
        [x, np.random.default_rng(3).uniform([0, 0, 0, 0], [1, 1, 1, 40000], (500, 4))]
    )
    expected = regressor.predict(probe)
    assert_allclose(forest.predict(probe), expected, rtol=0, atol=1e-9)
    for row in probe[::97]:
        assert forest.predict_one(row) == pytest.approx(regressor.predict(row[None])[0], abs=1e-9)
    assert forest.n_trees == 40 and forest.depth == max(
        e.tree_.max_depth for e in regressor.estimators_
    )


def test_features_per_tick_equal_whole_record() -> None:
    """Door features stepped per tick, or over a record split in two, equal the whole record's."""
    features = DoorFeatures("door_open", (60.0, 600.0))
    door = door_record(2000, seed=4)
    state0 = features.initial_state(door[0])
    whole, final = features.record(door, DT_S, state0)
    state = state0.copy()
    ticks = np.array([features.step(state, v, DT_S) for v in door])
    assert_allclose(ticks, whole, rtol=0, atol=1e-9)
    assert_allclose(state, final, rtol=0, atol=1e-9)
    first, middle = features.record(door[:777], DT_S, state0)
    second, end = features.record(door[777:], DT_S, middle)
    assert_allclose(np.vstack([first, second]), whole, rtol=0, atol=1e-9)
    assert_allclose(end, final, rtol=0, atol=1e-9)


def test_features_follow_the_causal_logistic() -> None:
    """A smoothed feature is tanh(t / 2 tau) after opening (eq. 9 from the change) and restarts there on closing."""
    features = DoorFeatures("door_open", (100.0,))
    door = np.r_[np.zeros(5), np.ones(10), np.zeros(10)]
    x, _ = features.record(door, DT_S, features.initial_state(0.0))
    t_open = DT_S * np.arange(10)
    assert_allclose(x[5:15, 0], np.tanh(t_open / 200.0), atol=1e-12)
    assert_allclose(x[5:15, 1], t_open)
    at_close = np.tanh(100.0 / 200.0)
    assert_allclose(x[15:, 0], at_close * (1 - np.tanh(t_open / 200.0)), atol=1e-12)
    assert np.all(x[:5, 0] == 0.0) and np.all(x[:5, 1] == features.cap_s)


def test_forest_refuses_inconsistent_arrays() -> None:
    """A forest whose children point backwards (a cycle) or out of range is refused at construction."""
    good = dict(
        roots=np.array([0]), left=np.array([1, 1, 2]), right=np.array([2, 1, 2]),
        feature=np.array([0, 0, 0]), threshold=np.array([0.5, 0, 0]),
        value=np.array([0.0, -1.0, 1.0]), n_features=1,
    )  # fmt: skip
    assert Forest(**good).predict(np.array([[0.0], [1.0]])).tolist() == [-1.0, 1.0]
    with pytest.raises(ModelError, match="after their parent"):
        Forest(**{**good, "left": np.array([0, 1, 2]), "right": np.array([2, 1, 2])})
    with pytest.raises(ModelError, match="out of range"):
        Forest(**{**good, "right": np.array([5, 1, 2])})


@pytest.fixture(scope="module")
def stacked_model(fitted) -> Model:
    """One first-order TF on a temperature plus a residual forest on the door signal."""
    regressor, _, features = fitted
    residual = ResidualModel(features, forest_from_sklearn(regressor))
    tf = DiscreteTF.from_coefficients([0.0, 0.05], [1.0, -0.95], 0)
    sub = SubModel("T_a", "temperature", InputSpec("T_a_degC"), tf)
    return Model("stacked", DT_S, (Output("disp_z_um", (sub,), residual),))


def test_tick_runner_equals_simulate_with_residual(stacked_model) -> None:
    """TickRunner adds the residual per tick as simulate does over a record; its saved state resumes mid-way."""
    compiled = compile_model(stacked_model)
    assert compiled.signals == ("T_a_degC", "door_open")
    door = door_record(600, seed=5)
    temperature = 20.0 + np.cumsum(np.random.default_rng(6).normal(0, 0.02, door.size))
    signals = np.column_stack([temperature, door])
    start = compiled.steady_state(signals[0])
    whole = simulate(compiled, signals, start)
    runner = TickRunner(compiled, start)
    ticks = np.array([runner.step(row) for row in signals])
    assert_allclose(ticks, whole.outputs, rtol=0, atol=1e-9)
    assert whole.residuals is not None and np.ptp(whole.residuals) > 1.0
    runner = TickRunner(compiled, start)
    for row in signals[:300]:
        runner.step(row)
    saved = ModelState.from_dict(runner.state.to_dict())
    rest = simulate(compiled, signals[300:], saved)
    assert_allclose(rest.outputs, whole.outputs[300:], rtol=0, atol=1e-9)
    assert_allclose(rest.final_state.residual, whole.final_state.residual, atol=1e-9)


def test_state_of_another_model_is_refused(stacked_model) -> None:
    """A saved state without the residual-feature values (a plain TF model's) is refused by a stacked model."""
    compiled = compile_model(stacked_model)
    plain = ModelState.from_dict({"z": [[0.0]], "reference": [20.0]})
    with pytest.raises(ModelError, match="residual-feature"):
        TickRunner(compiled, plain)
