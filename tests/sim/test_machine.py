"""The simulated machine's parameters, heat laws and displacement geometry."""

import numpy as np
import pytest

from compd.sim.machine import (
    NODES,
    Geometry,
    Link,
    MachineParameters,
    displacement_matrix,
    heat_inputs_w,
    node,
    noload_power_kw,
)

X, Y, Z = 0, 1, 2


def rise(**kelvin: float) -> np.ndarray:
    t = np.zeros(len(NODES))
    for name, value in kelvin.items():
        t[node(name)] = value
    return t


def test_column_gradient_bends_y_with_opposite_signs() -> None:
    """A column front warmer than its back tilts the spindle towards -y; the reverse gradient towards +y."""
    m = displacement_matrix(Geometry())
    front_warm = m @ rise(column_front=1.0)
    back_warm = m @ rise(column_back=1.0)
    assert front_warm[Y] < -5.0 and back_warm[Y] > 5.0
    np.testing.assert_allclose(front_warm[Y], -back_warm[Y])


def test_uniform_column_warming_lifts_the_spindle_without_bending() -> None:
    """A column warming evenly grows upwards (+z, about 10 um per K for 0.9 m of cast iron) and does not bend."""
    d = displacement_matrix(Geometry()) @ rise(column_front=1.0, column_back=1.0)
    assert d[Y] == pytest.approx(0.0, abs=1e-12)
    assert d[Z] == pytest.approx(10.5e-6 * 0.9 * 1e6)


def test_spindle_and_headstock_growth_close_the_gap_while_column_growth_opens_it() -> None:
    """Spindle, headstock, Z screw and table growth move the tool towards the table (-z): opposite to the column's."""
    m = displacement_matrix(Geometry())
    for name in ("shaft", "bearings", "headstock", "nut_z", "table"):
        assert m[Z, node(name)] < 0, name
    assert m[Z, node("column_front")] > 0


def test_headstock_growth_pushes_the_spindle_forwards() -> None:
    """The headstock's growth moves the spindle axis away from the column (+y), against the front-warm bending."""
    assert displacement_matrix(Geometry())[Y, node("headstock")] > 0


def test_x_screw_heat_expands_x() -> None:
    """A warmer X ball screw moves x by alpha_steel * position per K (5.75 um/K at 0.5 m)."""
    d = displacement_matrix(Geometry()) @ rise(nut_x=1.0)
    assert d[X] == pytest.approx(11.5e-6 * 0.5 * 1e6)


def test_bearing_friction_grows_faster_than_speed() -> None:
    """Doubling the spindle speed more than doubles the bearing friction heat (exponent 1.7)."""
    params = MachineParameters()
    zeros = np.zeros(2)
    q = heat_inputs_w(params, np.array([5000.0, 10000.0]), zeros, zeros, zeros)
    friction = q[node("bearings")] + q[node("shaft")]
    assert friction[1] / friction[0] == pytest.approx(2**1.7)


def test_cutting_feed_and_idle_heat_go_where_the_laws_say() -> None:
    """Cutting heat reaches the table and the motor, feed heat the nuts, and a stopped machine only heats its air."""
    params = MachineParameters()
    q = heat_inputs_w(
        params, np.array([0.0, 3000.0]), np.array([0.0, 5.0]), np.array([0.0, 10000.0]), np.zeros(2)
    )
    idle, busy = q[:, 0], q[:, 1]
    assert np.flatnonzero(idle).tolist() == [node("air")]
    assert busy[node("table")] == pytest.approx(params.heat.cut_to_table * 5000.0)
    assert busy[node("nut_x")] == pytest.approx(params.heat.k_feed_w_per_mm_per_min * 10000.0)
    assert busy[node("nut_z")] == 0.0


def test_noload_power_is_small_and_zero_at_rest() -> None:
    """The drive draws no power at standstill and well under 1 kW turning free at top speed."""
    p = noload_power_kw(MachineParameters(), np.array([0.0, 12000.0]))
    assert p[0] == 0.0 and 0.1 < p[1] < 1.0


def test_a_link_to_an_unknown_node_is_refused() -> None:
    """Parameters naming a node that does not exist are an error, not a silently ignored link."""
    with pytest.raises(ValueError, match="unknown node"):
        MachineParameters(links=(Link("bearings", "gearbox", 1.0),))
