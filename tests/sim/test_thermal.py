"""The thermal network: exact integration, steady state, speed and door dependence, step API."""

import numpy as np
import pytest
import scipy.linalg
from numpy.testing import assert_allclose

from compd.sim.machine import N_NODES, heat_inputs_w, node
from compd.sim.thermal import (
    InputRecord,
    MachineInputs,
    MachineTwin,
    ThermalNetwork,
    equilibrium,
    simulate_record,
)


def constant_record(n: int, **values: float) -> InputRecord:
    def col(name: str, default: float = 0.0) -> np.ndarray:
        return np.full(n, float(values.get(name, default)))

    return InputRecord(
        col("T_ambient_degC", 20.0),
        col("T_coolant_degC", 20.0),
        col("spindle_speed_rpm"),
        col("cutting_power_kw"),
        col("feed_x_mm_per_min"),
        col("feed_z_mm_per_min"),
        col("door_open"),
    )


@pytest.fixture(scope="module")
def network() -> ThermalNetwork:
    return ThermalNetwork()


def test_constant_inputs_converge_to_the_analytic_steady_state(network: ThermalNetwork) -> None:
    """Held inputs drive every node to the solution of K T = q + B [T_a, T_c] (3 days at 60 s)."""
    n = 3 * 24 * 60
    u = constant_record(
        n, spindle_speed_rpm=8000, cutting_power_kw=3, feed_x_mm_per_min=5000, T_coolant_degC=22
    )
    record = simulate_record(u, 60.0)
    heat = heat_inputs_w(
        network.params, np.array([8000.0]), np.array([3.0]), np.array([5000.0]), np.zeros(1)
    )[:, 0]
    expected = network.steady_state(8000.0, False, heat, 20.0, 22.0)
    assert_allclose(record.temperatures_degC[:, -1], expected, atol=1e-3)


def test_steady_state_balances_the_heat_flows(network: ThermalNetwork) -> None:
    """In equilibrium the heat sources equal the heat leaving to ambient and coolant (energy balance)."""
    heat = heat_inputs_w(
        network.params, np.array([10000.0]), np.array([5.0]), np.zeros(1), np.zeros(1)
    )[:, 0]
    t = network.steady_state(10000.0, False, heat, 20.0, 21.0)
    op = network.operating_point(10000.0, False)
    out_w = op.boundary_w_per_k[:, 0] @ (t - 20.0) + op.boundary_w_per_k[:, 1] @ (t - 21.0)
    assert out_w == pytest.approx(heat.sum(), rel=1e-9)


def test_discretisation_matches_the_matrix_exponential(network: ThermalNetwork) -> None:
    """The modal ZOH update equals expm of the augmented continuous system, computed independently."""
    ts = 10.0
    d = network.discretisation(6000.0, True, ts)
    op = network.operating_point(6000.0, True)
    c = np.asarray(network.params.capacity_j_per_k)
    a = -op.conductance_w_per_k / c[:, None]
    b = np.eye(N_NODES) / c[:, None]
    aug = np.zeros((2 * N_NODES, 2 * N_NODES))
    aug[:N_NODES, :N_NODES] = a
    aug[:N_NODES, N_NODES:] = b
    phi = scipy.linalg.expm(aug * ts)
    assert_allclose(d.a, phi[:N_NODES, :N_NODES], atol=1e-12)
    assert_allclose(d.b_forcing, phi[:N_NODES, N_NODES:], rtol=1e-9, atol=1e-15)


def test_time_constants_span_minutes_to_hours(network: ThermalNetwork) -> None:
    """The network's modes range from about a minute or less (air) to several hours (bed and column)."""
    tau_s = network.discretisation(0.0, False, 1.0).time_constants_s
    assert tau_s.max() > 4 * 3600
    assert tau_s.min() < 120


def test_record_and_step_by_step_twin_agree() -> None:
    """simulate_record and MachineTwin.step give the same temperatures and displacements."""
    rng = np.random.default_rng(1)
    n = 400
    u = constant_record(n)
    speed = np.repeat(rng.choice([0.0, 3000.0, 9000.0], n // 40), 40)
    door = np.repeat(rng.integers(0, 2, n // 50).astype(float), 50)
    u = InputRecord(
        20 + 0.01 * np.arange(n),
        u.T_coolant_degC,
        speed,
        rng.uniform(0, 5, n),
        rng.uniform(0, 8000, n),
        rng.uniform(0, 8000, n),
        door,
    )
    record = simulate_record(u, 10.0)
    twin = MachineTwin(MachineInputs(20.0, 20.0), sample_time_s=10.0)
    for k in range(n - 1):
        state = twin.step(u.at(k))
        assert_allclose(state.temperatures_degC, record.temperatures_degC[:, k + 1], atol=1e-9)
    assert_allclose(state.displacement_um, record.displacement_um[:, -1], atol=1e-8)


def test_a_cold_machine_at_rest_stays_put_with_zero_displacement() -> None:
    """Started in equilibrium at rest, an idle machine in a constant shop does not move at all."""
    record = simulate_record(constant_record(200), 10.0)
    assert_allclose(record.displacement_um, 0.0, atol=1e-9)


def test_spindle_heats_faster_than_it_cools() -> None:
    """After a speed step the shaft reaches 63 % of its rise sooner than it loses 63 % after the stop."""
    half = 6 * 3600 // 10
    speed = np.r_[np.full(half, 10000.0), np.zeros(half)]
    u = constant_record(2 * half)
    u = InputRecord(
        u.T_ambient_degC,
        u.T_coolant_degC,
        speed,
        u.cutting_power_kw,
        u.feed_x_mm_per_min,
        u.feed_z_mm_per_min,
        u.door_open,
    )
    shaft = simulate_record(u, 10.0).temperature("shaft")
    heating, cooling = shaft[:half] - shaft[0], shaft[half - 1] - shaft[half:]
    peak = shaft[half - 1] - shaft[0]
    t_heat = np.argmax(heating >= 0.632 * peak)
    t_cool = np.argmax(cooling >= 0.632 * (shaft[half - 1] - shaft[-1]))
    assert 0 < t_heat < t_cool


def test_an_open_door_cools_the_enclosure_air_towards_ambient() -> None:
    """Opening the door for 10 min cuts the air's excess over ambient below 20 %; shutting it warms the air again."""
    twin = MachineTwin(MachineInputs(20.0, 20.0), sample_time_s=10.0)
    closed = twin.state.temperature("air") - 20.0
    assert closed > 1.0
    for _ in range(60):
        opened = twin.step(MachineInputs(20.0, 20.0, door_open=True)).temperature("air") - 20.0
    for _ in range(60):
        shut = twin.step(MachineInputs(20.0, 20.0)).temperature("air") - 20.0
    assert 0 < opened < 0.2 * closed
    assert shut > 0.7 * closed


def test_warmer_coolant_warms_the_table() -> None:
    """A coolant 4 degC above ambient takes the table most of the way with it."""
    net = ThermalNetwork()
    t = equilibrium(net, MachineInputs(20.0, 24.0))
    assert 22.5 < t[node("table")] < 24.0


def test_twin_refuses_a_sample_time_of_zero() -> None:
    """A twin needs a positive sample time."""
    with pytest.raises(ValueError, match="sample_time_s"):
        MachineTwin(MachineInputs(20.0, 20.0), sample_time_s=0.0)
