"""The compile-time bounds: a model beyond them is a ModelError naming the sub-model, before any state is allocated."""

from __future__ import annotations

import numpy as np
import pytest

from compd.errors import ModelError
from compd.model import ContinuousTF, DiscreteTF, InputSpec, Model, Output, SubModel, compile_model
from compd.model.limits import (
    MAX_DELAY_SAMPLES,
    MAX_GAIN_UM_PER_UNIT,
    MAX_ORDER,
    MAX_SAMPLE_TIME_S,
    MAX_STATES,
    MAX_SUBMODELS,
)

from .conftest import first_order, single


def many(count: int, tf: DiscreteTF) -> Model:
    subs = tuple(
        SubModel(f"s{i}", "e", InputSpec("T_degC", reference=0.0), tf) for i in range(count)
    )
    return Model("many", 1.0, (Output("disp_z_um", subs),))


def test_an_absurd_gain_is_refused_naming_the_sub_model() -> None:
    """``gain: 1e308`` is refused at compile as an absurd static gain, naming the sub-model."""
    with pytest.raises(ModelError, match=r"static gain 1e\+308 um per input unit") as info:
        compile_model(single(first_order(1.0, 0.5), gain=1e308))
    assert info.value.where == "outputs.disp_z_um.submodels[0] (heat)"


def test_coefficients_that_overflow_are_refused() -> None:
    """Coefficients ``[1e308, 1e308]`` (B(1) = inf) are refused, not compiled into an inf gain."""
    with pytest.raises(ModelError, match="static gain inf"):
        compile_model(single(DiscreteTF.from_coefficients([1e308, 1e308], [1.0, -0.5])))


def test_a_gain_just_within_the_bound_compiles() -> None:
    """The bound is inclusive of sensible models: 1e5 um per unit compiles."""
    compiled = compile_model(single(first_order(1.0, 0.5), gain=MAX_GAIN_UM_PER_UNIT / 10))
    assert compiled.n_submodels == 1


def test_a_delay_beyond_the_bound_is_refused_before_allocating() -> None:
    """``nk`` of a million (a 7 TiB step matrix) or 1e10 is refused when the TF is built."""
    for nk in (MAX_DELAY_SAMPLES + 1, 1_000_000, 10**10):
        with pytest.raises(ModelError, match=f"up to|exceeds the {MAX_DELAY_SAMPLES}"):
            DiscreteTF.from_coefficients([1.0], [1.0, -0.5], nk)
    assert DiscreteTF.from_coefficients([1.0], [1.0, -0.5], MAX_DELAY_SAMPLES).nk == 600


def test_a_continuous_delay_beyond_the_bound_is_refused_at_discretisation() -> None:
    """``delay_s: 1e15`` is refused as too many samples, not allocated."""
    tf = ContinuousTF.from_coefficients([1.0], [1.0, 100.0], delay_s=1e15)
    with pytest.raises(ModelError, match="compd runs delays up to 600 samples") as info:
        compile_model(single(tf))
    assert "submodels[0]" in info.value.where


def test_an_order_beyond_the_bound_is_refused() -> None:
    """A denominator of 3000 coefficients (minutes of root finding) is refused at once."""
    with pytest.raises(ModelError, match=f"up to order {MAX_ORDER}"):
        DiscreteTF.from_coefficients([1.0], np.r_[1.0, np.full(2999, 1e-4)])
    with pytest.raises(ModelError, match=f"up to order {MAX_ORDER}"):
        ContinuousTF.from_coefficients(np.ones(10**6), [1.0, 1.0])


def test_too_many_sub_models_are_refused() -> None:
    """20,000 sub-models (or one over the bound) are refused before any is discretised."""
    for count in (MAX_SUBMODELS + 1, 20_000):
        with pytest.raises(
            ModelError, match=f"{count} sub-models; compd runs up to {MAX_SUBMODELS}"
        ):
            compile_model(many(count, first_order(1.0, 0.5)))


def test_too_many_states_are_refused() -> None:
    """Sub-models x delay line beyond the state bound is refused, naming both factors."""
    tf = first_order(0.001, 0.5, nk=MAX_DELAY_SAMPLES)
    with pytest.raises(ModelError, match=f"compd runs up to {MAX_STATES}"):
        compile_model(many(MAX_STATES // MAX_DELAY_SAMPLES + 1, tf))


def test_extreme_continuous_coefficients_are_a_model_error_not_a_linalg_error() -> None:
    """A denominator ``[1, 1e-300]`` (a pole at -1e300 1/s) is a ModelError, not scipy's LinAlgError."""
    with pytest.raises(ModelError, match="orders of magnitude"):
        compile_model(single(ContinuousTF.from_coefficients([1.0], [1.0, 1e-300])))


def test_an_absurd_sample_time_is_refused() -> None:
    """A run sample time of 1e308 s (a config's ``period_s``) is refused before discretising."""
    model = single(ContinuousTF.from_coefficients([1.0], [1.0, 100.0]))
    with pytest.raises(ModelError, match=f"<= {MAX_SAMPLE_TIME_S:g} s"):
        compile_model(model, 1e308)


def test_a_huge_transient_is_refused_by_the_step_simulation() -> None:
    """A TF whose static gain is 0 but whose step response peaks at 1e7 um is refused by the short simulation."""
    tf = DiscreteTF.from_coefficients([1e7, -1e7], [1.0, -0.5])
    assert tf.static_gain() == 0.0
    with pytest.raises(ModelError, match="unit-step response reaches 1e\\+07 um") as info:
        compile_model(single(tf))
    assert info.value.where.startswith("outputs.disp_z_um.submodels[0]")
