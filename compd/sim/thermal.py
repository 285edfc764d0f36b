"""The machine's lumped thermal network and its exact integration.

Node temperatures ``T`` (degC, shape ``(N,)``) obey::

    C dT/dt = −K(n, door) T + q(t) + B [T_ambient(t), T_coolant(t)]ᵀ

with ``C`` the diagonal heat capacities (J/K), ``K`` the conductance matrix
(W/K: the weighted Laplacian of the node links plus every node's conductance
to the boundaries on its diagonal), ``q`` the heat sources (W) and ``B`` the
boundary conductances (W/K). ``K`` depends on the operating point only: the
spindle speed ``n`` (forced convection) and the door (air exchange).

Within one operating point the system is linear and time-invariant, so it is
integrated *exactly* for inputs held over each sample (zero-order hold). As
``C^{-1/2} K C^{-1/2} = W diag(μ) Wᵀ`` is symmetric, the network has real
modes ``μ_i > 0`` (1/s) and, in modal coordinates ``z = Wᵀ C^{1/2} T``::

    z_i[k+1] = e^{−μ_i Ts} z_i[k] + (1 − e^{−μ_i Ts}) / μ_i · (Wᵀ C^{−1/2} F[k])_i

with ``F = q + B [T_a, T_c]ᵀ`` in W. A whole record is run segment by
segment (one segment per operating point) with one first-order filter per
mode, so 24 h at 1 s takes a fraction of a second; :class:`MachineTwin`
offers the same update one tick at a time.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.signal import lfilter

from compd.sim.machine import (
    BOUNDARIES,
    N_NODES,
    NODES,
    MachineParameters,
    displacement_matrix,
    heat_inputs_w,
    node,
    speed_factor,
)


@dataclass(frozen=True, eq=False)
class OperatingPoint:
    """The network at one spindle speed and door state: ``K`` and ``B`` in W/K."""

    conductance_w_per_k: np.ndarray  # (N, N)
    boundary_w_per_k: np.ndarray  # (N, 2): to ambient, to coolant


@dataclass(frozen=True, eq=False)
class Discretisation:
    """Exact zero-order-hold update at one operating point: ``T+ = A T + Bf F``."""

    a: np.ndarray  # (N, N)
    b_forcing: np.ndarray  # (N, N), per W of forcing
    decay: np.ndarray  # (N,) e^{-μ Ts} per mode
    gain_s_per_j: np.ndarray  # (N,) (1 - e^{-μ Ts}) / μ, per mode
    to_modes: np.ndarray  # (N, N) Wᵀ C^{1/2}
    forcing_to_modes: np.ndarray  # (N, N) Wᵀ C^{-1/2}
    from_modes: np.ndarray  # (N, N) C^{-1/2} W
    time_constants_s: np.ndarray  # (N,) 1/μ, descending
    boundary_w_per_k: np.ndarray  # (N, 2) B of this operating point


class ThermalNetwork:
    """The network of one machine: operating points, discretisations (cached), steady states."""

    def __init__(self, params: MachineParameters | None = None) -> None:
        self.params = params or MachineParameters()
        self.capacity_j_per_k = np.asarray(self.params.capacity_j_per_k, dtype=float)
        self.displacement_um_per_k = displacement_matrix(self.params.geometry)
        self._discretise: Callable[[float, bool, float], Discretisation] = lru_cache(maxsize=512)(
            self._discretise_uncached
        )

    def operating_point(self, speed_rpm: float, door_open: bool) -> OperatingPoint:
        """``K`` and ``B`` at spindle speed ``speed_rpm`` with the door open or shut."""
        k = np.zeros((N_NODES, N_NODES))
        b = np.zeros((N_NODES, len(BOUNDARIES)))
        s = float(speed_factor(speed_rpm, self.params.heat.convection_exponent))
        for link in self.params.links:
            g = link.g0 + link.g_speed * s + (link.g_door if door_open else 0.0)
            i = node(link.a)
            k[i, i] += g
            if link.b in BOUNDARIES:
                b[i, BOUNDARIES.index(link.b)] += g
            else:
                j = node(link.b)
                k[j, j] += g
                k[i, j] -= g
                k[j, i] -= g
        return OperatingPoint(k, b)

    def discretisation(
        self, speed_rpm: float, door_open: bool, sample_time_s: float
    ) -> Discretisation:
        """Exact ZOH update over ``sample_time_s`` (cached per speed, door and sample time)."""
        return self._discretise(float(speed_rpm), bool(door_open), float(sample_time_s))

    def _discretise_uncached(
        self, speed_rpm: float, door_open: bool, sample_time_s: float
    ) -> Discretisation:
        op = self.operating_point(speed_rpm, door_open)
        root_c = np.sqrt(self.capacity_j_per_k)
        symmetric = op.conductance_w_per_k / np.outer(root_c, root_c)
        mu, w = np.linalg.eigh(symmetric)  # ascending rates, orthonormal modes
        if mu[0] <= 0:
            raise ValueError("the network has a node without a path to a boundary")
        decay = np.exp(-mu * sample_time_s)
        gain = -np.expm1(-mu * sample_time_s) / mu
        from_modes = w / root_c[:, None]
        to_modes = w.T * root_c[None, :]
        forcing_to_modes = w.T / root_c[None, :]
        return Discretisation(
            a=from_modes @ (decay[:, None] * to_modes),
            b_forcing=from_modes @ (gain[:, None] * forcing_to_modes),
            decay=decay,
            gain_s_per_j=gain,
            to_modes=to_modes,
            forcing_to_modes=forcing_to_modes,
            from_modes=from_modes,
            time_constants_s=1.0 / mu,
            boundary_w_per_k=op.boundary_w_per_k,
        )

    def steady_state(
        self,
        speed_rpm: float,
        door_open: bool,
        heat_w: np.ndarray,
        ambient_degc: float,
        coolant_degc: float,
    ) -> np.ndarray:
        """Equilibrium temperatures (degC) for constant inputs: ``K T = q + B [T_a, T_c]ᵀ``."""
        op = self.operating_point(speed_rpm, door_open)
        rhs = np.asarray(heat_w, dtype=float) + op.boundary_w_per_k @ [ambient_degc, coolant_degc]
        return np.asarray(np.linalg.solve(op.conductance_w_per_k, rhs))


@dataclass(frozen=True, eq=False)
class MachineInputs:
    """What drives the machine during one sample (held constant over it)."""

    T_ambient_degC: float
    T_coolant_degC: float
    spindle_speed_rpm: float = 0.0
    cutting_power_kw: float = 0.0
    feed_x_mm_per_min: float = 0.0
    feed_z_mm_per_min: float = 0.0
    door_open: bool = False


@dataclass(frozen=True, eq=False)
class InputRecord:
    """:class:`MachineInputs` as arrays, one value per sample (all the same length)."""

    T_ambient_degC: np.ndarray
    T_coolant_degC: np.ndarray
    spindle_speed_rpm: np.ndarray
    cutting_power_kw: np.ndarray
    feed_x_mm_per_min: np.ndarray
    feed_z_mm_per_min: np.ndarray
    door_open: np.ndarray

    def __len__(self) -> int:
        return len(self.T_ambient_degC)

    def at(self, k: int) -> MachineInputs:
        """Sample ``k`` as :class:`MachineInputs`."""
        return MachineInputs(
            T_ambient_degC=float(self.T_ambient_degC[k]),
            T_coolant_degC=float(self.T_coolant_degC[k]),
            spindle_speed_rpm=float(self.spindle_speed_rpm[k]),
            cutting_power_kw=float(self.cutting_power_kw[k]),
            feed_x_mm_per_min=float(self.feed_x_mm_per_min[k]),
            feed_z_mm_per_min=float(self.feed_z_mm_per_min[k]),
            door_open=bool(self.door_open[k] > 0.5),
        )


def _heat(params: MachineParameters, u: MachineInputs | InputRecord) -> np.ndarray:
    return heat_inputs_w(
        params,
        np.atleast_1d(u.spindle_speed_rpm),
        np.atleast_1d(u.cutting_power_kw),
        np.atleast_1d(u.feed_x_mm_per_min),
        np.atleast_1d(u.feed_z_mm_per_min),
    )


def equilibrium(network: ThermalNetwork, u: MachineInputs) -> np.ndarray:
    """Node temperatures (degC) in equilibrium with constant inputs ``u``."""
    return network.steady_state(
        u.spindle_speed_rpm,
        u.door_open,
        _heat(network.params, u)[:, 0],
        u.T_ambient_degC,
        u.T_coolant_degC,
    )


@dataclass(frozen=True, eq=False)
class TwinState:
    """The machine at one instant: node temperatures (degC) and TCP displacement x, y, z (um)."""

    time_s: float
    temperatures_degC: np.ndarray  # (N,) in NODES order
    displacement_um: np.ndarray  # (3,) x, y, z

    def temperature(self, name: str) -> float:
        return float(self.temperatures_degC[node(name)])


class MachineTwin:
    """The thermal twin advanced one sample at a time, for closed-loop use (PLC, compensation).

    It starts in equilibrium with ``initial`` (or at ``initial_temperatures_degC``);
    displacements are measured from that start state, so they begin at zero.
    """

    def __init__(
        self,
        initial: MachineInputs,
        *,
        sample_time_s: float = 1.0,
        params: MachineParameters | None = None,
        initial_temperatures_degC: np.ndarray | None = None,
    ) -> None:
        if not sample_time_s > 0:
            raise ValueError(f"sample_time_s must be above 0, not {sample_time_s}")
        self.network = ThermalNetwork(params)
        self.sample_time_s = float(sample_time_s)
        start = (
            equilibrium(self.network, initial)
            if initial_temperatures_degC is None
            else np.array(initial_temperatures_degC, dtype=float)
        )
        self.reference_degC = start.copy()
        self._t = start
        self._time_s = 0.0

    @property
    def state(self) -> TwinState:
        rise = self._t - self.reference_degC
        return TwinState(self._time_s, self._t.copy(), self.network.displacement_um_per_k @ rise)

    def step(self, u: MachineInputs) -> TwinState:
        """Hold ``u`` for one sample time and return the state at its end."""
        d = self.network.discretisation(u.spindle_speed_rpm, u.door_open, self.sample_time_s)
        forcing = _heat(self.network.params, u)[:, 0] + d.boundary_w_per_k @ [
            u.T_ambient_degC,
            u.T_coolant_degC,
        ]
        self._t = d.a @ self._t + d.b_forcing @ forcing
        self._time_s += self.sample_time_s
        return self.state


@dataclass(frozen=True, eq=False)
class ThermalRecord:
    """True temperatures (degC, ``(N, samples)``) and displacements (um, ``(3, samples)``)."""

    temperatures_degC: np.ndarray
    displacement_um: np.ndarray

    def temperature(self, name: str) -> np.ndarray:
        return np.asarray(self.temperatures_degC[node(name)])


def simulate_record(
    inputs: InputRecord,
    sample_time_s: float,
    *,
    params: MachineParameters | None = None,
    initial_temperatures_degC: np.ndarray | None = None,
) -> ThermalRecord:
    """Run the network over a record: sample ``k`` holds the state after inputs ``0..k-1``.

    Sample 0 is the start state: a cold machine at rest (spindle stopped, door
    shut) in equilibrium with the first ambient and coolant temperatures,
    unless ``initial_temperatures_degC`` is given. The result equals
    :meth:`MachineTwin.step` applied sample by sample (to rounding).
    """
    network = ThermalNetwork(params)
    n = len(inputs)
    at_rest = MachineInputs(float(inputs.T_ambient_degC[0]), float(inputs.T_coolant_degC[0]))
    start = (
        equilibrium(network, at_rest)
        if initial_temperatures_degC is None
        else np.array(initial_temperatures_degC, dtype=float)
    )
    heat = _heat(network.params, inputs)
    boundary = np.vstack([inputs.T_ambient_degC, inputs.T_coolant_degC])
    speed = np.asarray(inputs.spindle_speed_rpm, dtype=float)
    door = np.asarray(inputs.door_open, dtype=float) > 0.5
    change = np.flatnonzero((np.diff(speed) != 0) | (np.diff(door) != 0)) + 1
    edges = [0, *change.tolist(), n]
    temps = np.empty((N_NODES, n))
    temps[:, 0] = start
    current = start
    for first, stop in itertools.pairwise(edges):
        # inputs first..stop-1 produce the states first+1..stop
        d = network.discretisation(speed[first], bool(door[first]), sample_time_s)
        forcing = heat[:, first:stop] + d.boundary_w_per_k @ boundary[:, first:stop]
        modal_forcing = d.forcing_to_modes @ forcing
        z0 = d.to_modes @ current
        modes = np.empty_like(modal_forcing)
        for i in range(N_NODES):
            modes[i], _ = lfilter(
                [d.gain_s_per_j[i]], [1.0, -d.decay[i]], modal_forcing[i], zi=[d.decay[i] * z0[i]]
            )
        states = d.from_modes @ modes
        last = min(stop, n - 1)
        temps[:, first + 1 : last + 1] = states[:, : last - first]
        current = states[:, -1]
    rise = temps - start[:, None]
    return ThermalRecord(temps, network.displacement_um_per_k @ rise)


__all__ = [
    "NODES",
    "InputRecord",
    "MachineInputs",
    "MachineTwin",
    "ThermalNetwork",
    "ThermalRecord",
    "TwinState",
    "equilibrium",
    "simulate_record",
]
