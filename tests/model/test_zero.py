"""The thermal zero at start: fixed references moved with the shop air, or today's readings on a cold machine."""

from __future__ import annotations

import numpy as np

from compd.model import compile_model
from compd.model.structure import AmbientZero, InputSpec, Model, Output, SubModel
from compd.model.transfer import DiscreteTF
from compd.model.zero import COLD_BAND_DEGC

LAG = DiscreteTF.from_coefficients([0.1], [1.0, -0.9], 1)


def model() -> Model:
    subs = (
        SubModel("spindle", "spindle", InputSpec("T_spindle_degC", reference=22.0), LAG),
        SubModel("air", "air", InputSpec("T_ambient_degC", reference=20.0), LAG),
        SubModel("power", "cutting", InputSpec("power_kw", reference=0.0), LAG),
    )
    air = AmbientZero("T_ambient_degC", 20.0, ("T_spindle_degC", "T_ambient_degC"))
    return Model("zero", 1.0, (Output("disp_z_um", subs),), air)


def test_a_warm_machine_starts_from_the_zero_moved_with_the_air_and_a_power_keeps_its_zero() -> (
    None
):
    """Air 1 degC warmer, spindle 5 degC above: references 23 / 21 degC, the power's stays 0 kW."""
    compiled = compile_model(model())
    values = {"T_spindle_degC": 28.0, "T_ambient_degC": 21.0, "power_kw": 3.0}
    assert not compiled.reads_cold(values)
    assert compiled.steady_state(values).reference.tolist() == [23.0, 21.0, 0.0]


def test_a_machine_within_the_cold_band_takes_its_temperatures_as_the_zero() -> None:
    """Every temperature within the band of its moved zero: the temperatures' references are today's readings."""
    compiled = compile_model(model())
    spindle = 23.0 + 0.9 * COLD_BAND_DEGC
    values = {"T_spindle_degC": spindle, "T_ambient_degC": 21.0, "power_kw": 3.0}
    assert compiled.reads_cold(values)
    assert np.allclose(compiled.steady_state(values).reference, [spindle, 21.0, 0.0])
