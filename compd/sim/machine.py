"""The simulated milling centre: its thermal nodes, couplings, heat sources and geometry.

A 3-axis vertical milling centre (C-frame: a column on the bed, a headstock
sliding in Z on the column front, a table on a saddle in front of it) reduced
to lumped thermal nodes. Everything here is *data and formulas*: heat
capacities (J/K), conductances (W/K), heat-source laws (W) and the linear map
from temperature rises to the tool centre point (TCP) displacement (um). The
network itself is assembled and integrated in :mod:`compd.sim.thermal`.

The values are order-of-magnitude engineering estimates for a machine with a
12,000 rpm spindle, a 1.5 t column and a 3 t bed, chosen so that the time
constants span ~10 min (spindle bearings) to several hours (bed, column), as
measured on such machines (Horejs 2010 and Horejs 2015), and so that each
"hidden" effect (cutting heat, feed-drive heat, door openings, coolant
temperature) acts through a part that none of the machine's temperature
sensors sees: the table/workpiece, the ball screws, the spindle shaft and
the enclosure air.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: Thermal nodes, in state-vector order.
NODES: tuple[str, ...] = (
    "bearings",  # front spindle bearings' outer rings and the housing around them
    "shaft",  # spindle shaft and bearing inner rings (rotating; no sensor)
    "motor",  # spindle motor (on top of the headstock)
    "headstock",  # headstock casting / Z slide
    "column_front",  # front half of the column (guideway side, inside the enclosure)
    "column_back",  # back half of the column (faces the shop)
    "bed",
    "table",  # table, fixture and workpiece
    "nut_x",  # X ball-screw nut and the screw shaft it heats
    "nut_z",  # Z ball-screw nut and shaft
    "air",  # enclosure air and its sheet metal
)
N_NODES = len(NODES)
_INDEX = {name: i for i, name in enumerate(NODES)}


def node(name: str) -> int:
    """Index of a node in the state vector."""
    return _INDEX[name]


#: Thermal expansion coefficients, 1/K.
ALPHA_STEEL_PER_K = 11.5e-6
ALPHA_CAST_IRON_PER_K = 10.5e-6


@dataclass(frozen=True)
class Link:
    """A conductance between two nodes, or between a node and a boundary, in W/K.

    ``g_w_per_k = g0 + g_speed * (n / 1000 rpm)^0.6 + g_door * door_open``: the
    speed term is forced convection from the turning spindle, the door term
    the air exchange of an open door (boundary links only).
    """

    a: str
    b: str  # a node name, or "ambient" / "coolant"
    g0: float
    g_speed: float = 0.0
    g_door: float = 0.0


@dataclass(frozen=True)
class HeatLaws:
    """Heat sources in W, and the spindle power the controller reports, in kW.

    - bearing friction ``q_b = k_bearing * (n/1000)^1.7`` (faster than linear in speed),
      ``bearing_to_shaft`` of it into the inner rings and shaft, the rest into the outer rings
    - motor losses ``q_m = (k_motor0 + k_motor1 * n/1000) [n > 0] + motor_load_loss * P_cut``
    - cutting heat ``P_cut`` split: ``cut_to_shaft`` into the tool and spindle nose,
      ``cut_to_table`` into workpiece, fixture and table; the rest leaves with chips and coolant
    - ball-screw nuts ``q = k_feed * |feed|`` per axis (feed in mm/min)
    - ``q_aux`` into the enclosure air: coolant pump, chip conveyor, hydraulics, lights;
      it keeps the enclosure air about 5 degC above the shop, which an open door loses
    """

    k_bearing_w: float = 4.0
    bearing_exponent: float = 1.7
    bearing_to_shaft: float = 0.4
    k_motor0_w: float = 30.0
    k_motor1_w: float = 12.0
    motor_load_loss: float = 0.06
    cut_to_shaft: float = 0.005
    cut_to_table: float = 0.12
    k_feed_w_per_mm_per_min: float = 1.6e-3
    q_aux_w: float = 450.0
    convection_exponent: float = 0.6


@dataclass(frozen=True)
class Geometry:
    """Lever arms of the TCP displacement, in m (see :func:`displacement_matrix`)."""

    column_height_m: float = 0.9  # bed to the headstock's working height
    column_depth_m: float = 0.6  # front to back wall distance (bending)
    spindle_drop_m: float = 0.35  # column top region to spindle nose, vertical
    headstock_length_z_m: float = 0.30
    shaft_length_z_m: float = 0.30  # spindle shaft below its axial locating bearing
    cartridge_length_z_m: float = 0.15  # bearing cartridge below the headstock
    spindle_offset_y_m: float = 0.35  # spindle axis in front of the Z guideways
    motor_offset_x_m: float = 0.05  # asymmetric heating of the headstock by the belt-driven motor
    table_height_m: float = 0.40  # table + fixture + workpiece above the guideways
    x_screw_position_m: float = 0.50  # working position from the X screw's fixed bearing
    z_screw_position_m: float = 0.50  # headstock position from the Z screw's fixed bearing


@dataclass(frozen=True)
class MachineParameters:
    """All parameters of the simulated machine; the defaults are the reference machine."""

    capacity_j_per_k: tuple[float, ...] = (
        7e3,  # bearings and cartridge housing: ~15 kg of steel
        6e3,  # shaft: ~13 kg of steel
        30e3,  # motor: ~60 kg of iron and copper
        120e3,  # headstock: ~250 kg cast iron
        375e3,  # column front: half of ~1.5 t
        375e3,  # column back
        1.5e6,  # bed: ~3 t
        250e3,  # table + fixture + workpiece
        4e3,  # X screw and nut
        3.5e3,  # Z screw and nut
        3e3,  # enclosure air (~2.5 m³)
    )
    links: tuple[Link, ...] = (
        Link("bearings", "headstock", 12.0),
        Link("bearings", "air", 0.5, g_speed=1.5),
        Link("shaft", "bearings", 4.0),  # through the rolling elements
        Link("shaft", "motor", 2.0),  # rotor side
        Link("shaft", "air", 0.3, g_speed=1.5),  # spinning nose and tool
        Link("motor", "headstock", 8.0),
        Link("motor", "ambient", 40.0),  # fan-cooled, outside the enclosure
        Link("headstock", "column_front", 20.0),
        Link("headstock", "air", 2.0, g_speed=2.0),
        Link("headstock", "ambient", 4.0),
        Link("column_front", "column_back", 60.0),
        Link("column_front", "air", 5.0),
        Link("column_back", "ambient", 18.0),
        Link("column_front", "bed", 15.0),
        Link("column_back", "bed", 15.0),
        Link("bed", "ambient", 30.0),
        Link("bed", "coolant", 40.0),  # chip trough
        Link("table", "bed", 25.0),
        Link("table", "coolant", 120.0),  # flood coolant over table and workpiece
        Link("table", "air", 8.0),
        Link("nut_x", "air", 0.8),
        Link("nut_x", "bed", 4.0),  # screw bearings and guideway on the bed
        Link("nut_z", "air", 7.0),  # the Z screw runs in the enclosure air
        Link("nut_z", "column_front", 1.0),
        Link("air", "ambient", 60.0, g_door=600.0),  # leaks and mist extractor; open door
        Link("air", "coolant", 10.0),
    )
    heat: HeatLaws = field(default_factory=HeatLaws)
    geometry: Geometry = field(default_factory=Geometry)

    def __post_init__(self) -> None:
        if len(self.capacity_j_per_k) != N_NODES or min(self.capacity_j_per_k) <= 0:
            raise ValueError(f"capacity_j_per_k needs {N_NODES} positive values")
        for link in self.links:
            if link.a not in _INDEX or (link.b not in _INDEX and link.b not in BOUNDARIES):
                raise ValueError(f"link {link.a}-{link.b} names an unknown node")


BOUNDARIES = ("ambient", "coolant")


def speed_factor(speed_rpm: np.ndarray | float, exponent: float) -> np.ndarray:
    """``(n / 1000 rpm)^exponent``, 0 at standstill (the base of the speed laws)."""
    n = np.abs(np.asarray(speed_rpm, dtype=float)) / 1000.0
    return np.asarray(np.power(n, exponent))


def noload_power_kw(params: MachineParameters, speed_rpm: np.ndarray | float) -> np.ndarray:
    """Power the spindle drive draws when not cutting (bearing friction + motor losses), in kW."""
    h = params.heat
    turning = np.abs(np.asarray(speed_rpm, dtype=float)) > 0
    q_b = h.k_bearing_w * speed_factor(speed_rpm, h.bearing_exponent)
    q_m = np.where(turning, h.k_motor0_w + h.k_motor1_w * speed_factor(speed_rpm, 1.0), 0.0)
    return np.asarray((q_b + q_m) / 1000.0)


def heat_inputs_w(
    params: MachineParameters,
    speed_rpm: np.ndarray,
    cutting_power_kw: np.ndarray,
    feed_x_mm_per_min: np.ndarray,
    feed_z_mm_per_min: np.ndarray,
) -> np.ndarray:
    """Heat flow into every node, W, shape ``(N_NODES, samples)`` (laws in :class:`HeatLaws`)."""
    h = params.heat
    speed = np.atleast_1d(np.asarray(speed_rpm, dtype=float))
    cut_w = 1000.0 * np.maximum(np.atleast_1d(np.asarray(cutting_power_kw, dtype=float)), 0.0)
    turning = np.abs(speed) > 0
    q = np.zeros((N_NODES, speed.size))
    friction_w = h.k_bearing_w * speed_factor(speed, h.bearing_exponent)
    q[node("bearings")] = (1.0 - h.bearing_to_shaft) * friction_w
    q[node("shaft")] = h.bearing_to_shaft * friction_w + h.cut_to_shaft * cut_w
    q[node("motor")] = (
        np.where(turning, h.k_motor0_w + h.k_motor1_w * speed_factor(speed, 1.0), 0.0)
        + h.motor_load_loss * cut_w
    )
    q[node("table")] = h.cut_to_table * cut_w
    q[node("nut_x")] = h.k_feed_w_per_mm_per_min * np.abs(feed_x_mm_per_min)
    q[node("nut_z")] = h.k_feed_w_per_mm_per_min * np.abs(feed_z_mm_per_min)
    q[node("air")] = h.q_aux_w
    return q


def displacement_matrix(geometry: Geometry) -> np.ndarray:
    """Map from node temperature rises (K) to TCP displacement (um), shape ``(3, N_NODES)``.

    The displacement is that of the tool relative to the table, in machine
    axes (z up, away from the table; y from the column towards the door)::

        x = α_s L_xs ΔT_nut_x + α_ci L_mx ΔT_headstock
        z = α_ci H (ΔT_cf + ΔT_cb)/2 − α_ci L_hs ΔT_headstock − α_s L_c ΔT_bearings
            − α_s L_sh ΔT_shaft − α_s L_zs ΔT_nut_z − α_ci L_t ΔT_table
        y = α_ci L_y ΔT_headstock − α_ci (ΔT_cf − ΔT_cb)/d · (H²/2 + H·L_drop)

    Column growth lifts the spindle (+z) while shaft, cartridge, headstock, Z screw
    and table growth close the gap (−z); a column front warmer than its back
    bends the column backwards (−y) while headstock growth pushes the spindle
    forwards (+y): effects of opposite signs on one axis.
    """
    g = geometry
    s, ci = ALPHA_STEEL_PER_K * 1e6, ALPHA_CAST_IRON_PER_K * 1e6  # um per m per K
    m = np.zeros((3, N_NODES))
    x, y, z = 0, 1, 2
    m[x, node("nut_x")] = s * g.x_screw_position_m
    m[x, node("headstock")] = ci * g.motor_offset_x_m
    bend = ci / g.column_depth_m * (g.column_height_m**2 / 2 + g.column_height_m * g.spindle_drop_m)
    m[y, node("headstock")] = ci * g.spindle_offset_y_m
    m[y, node("column_front")] = -bend
    m[y, node("column_back")] = bend
    m[z, node("column_front")] = ci * g.column_height_m / 2
    m[z, node("column_back")] = ci * g.column_height_m / 2
    m[z, node("headstock")] = -ci * g.headstock_length_z_m
    m[z, node("bearings")] = -s * g.cartridge_length_z_m
    m[z, node("shaft")] = -s * g.shaft_length_z_m
    m[z, node("nut_z")] = -s * g.z_screw_position_m
    m[z, node("table")] = -ci * g.table_height_m
    return m
