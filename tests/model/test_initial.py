"""Initial-state estimation: a record that starts mid-transient is judged from where the machine was."""

from __future__ import annotations

import numpy as np
from numpy.testing import assert_allclose

from compd.model.compiled import ModelState, compile_model
from compd.model.initial import estimate_initial_state
from compd.model.lagbank import lag_tf
from compd.model.metrics import fit_percent
from compd.model.run import simulate
from compd.model.structure import InputSpec, Model, Output, SubModel

DT_S = 15.0


def _model() -> Model:
    subs = (
        SubModel("slow", "e", InputSpec("T1"), lag_tf(4.0, 10800.0, DT_S)),
        SubModel("fast", "e", InputSpec("T2"), lag_tf(-2.0, 600.0, DT_S)),
    )
    return Model("m", DT_S, (Output("disp_um", subs),))


def test_a_record_split_mid_transient_is_fitted_from_its_estimated_state() -> None:
    """Cooling still under way at the split: the estimated start follows it, a steady start cannot."""
    compiled = compile_model(_model())
    n = 4 * 240  # 4 h at 15 s
    rng = np.random.default_rng(0)
    signals = np.column_stack([20 + rng.normal(0, 0.01, n), 20 + np.linspace(0, 1, n)])
    steady = compiled.steady_state(signals[0])
    hidden_z = steady.z.copy()
    hidden_z[0, 0] += 6.0  # the slow part still holds heat from before the split
    hidden = ModelState(hidden_z, steady.reference, steady.residual)
    measured = simulate(compiled, signals, hidden).output(compiled, "disp_um")

    from_steady = simulate(compiled, signals, steady).output(compiled, "disp_um")
    estimated = estimate_initial_state(compiled, signals, {"disp_um": measured}, steady, 240)
    from_estimate = simulate(compiled, signals, estimated).output(compiled, "disp_um")

    assert fit_percent(measured, from_steady) < 50.0
    assert fit_percent(measured, from_estimate) > 99.0
    assert_allclose(estimated.z[0, 0], hidden_z[0, 0], rtol=1e-3)


def test_a_record_that_starts_steady_keeps_its_steady_start() -> None:
    """Nothing to correct: the estimate leaves the state where it was."""
    compiled = compile_model(_model())
    signals = np.column_stack([np.full(480, 20.0), 20 + np.linspace(0, 2, 480)])
    steady = compiled.steady_state(signals[0])
    measured = simulate(compiled, signals, steady).output(compiled, "disp_um")
    estimated = estimate_initial_state(compiled, signals, {"disp_um": measured}, steady, 240)
    assert_allclose(estimated.z, steady.z, atol=1e-6)
