"""Feed-axis positions for the twin: the ``feed_positions`` run, whose X and Z errors depend on where the axes stand.

A ball screw is held axially by its fixed bearing and grows from there as it
warms, so the error it adds at the nut is proportional to the nut's distance
from that bearing (Pahk 2002 eq. 5, ``m1(T) * P``)::

    e_x(k) = α_s · X(k) · ΔT_nut_x(k)        (um, X in mm, α_s in um per mm per K)
    e_z(k) = −α_s · Z(k) · ΔT_nut_z(k)

:func:`compd.sim.machine.displacement_matrix` evaluates these at the fixed
working positions ``x_screw_position_m`` and ``z_screw_position_m``; here the
axes move among measurement positions while the ``feed`` scenario's rapid
motion heats their screws, and the displacement logged at the TCP is the one
at the axis's current position. Everything else (schedule, ambient, sensors,
noise) is the ``feed`` scenario of the same seed, so the rest of compd's
columns keep their contract; this run only *adds* columns:

- ``X_position_mm``, ``Z_position_mm``: axis positions from each screw's
  fixed bearing, as the PLC reports them (exact; the PLC knows them);
- ``T_x_screw_degC``, ``T_z_screw_degC``: Pt100s on the screw nuts (lag,
  class-A offset, noise as every other sensor).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from compd.sim.machine import ALPHA_STEEL_PER_K, MachineParameters
from compd.sim.scenarios import _Steps, check_run, scenario_inputs, simulate_scenario
from compd.sim.sensors import PT100_NOISE_DEGC, class_a_tolerance_degc, lag
from compd.sim.thermal import simulate_record

#: Measurement positions (mm from the fixed bearing) each axis dwells at.
X_STOPS_MM = (50.0, 150.0, 250.0, 350.0, 450.0, 550.0, 650.0, 750.0)
Z_STOPS_MM = (50.0, 150.0, 250.0, 350.0, 450.0)
#: Dwell at one position, minutes: several samples at 10 s, shorter than the screw's ~14 min.
DWELL_MIN = (2.0, 15.0)
SCREW_SENSOR_LAG_S = 30.0
#: Columns this run adds after the contract :data:`compd.sim.sensors.COLUMNS`.
POSITION_COLUMNS = ("X_position_mm", "Z_position_mm", "T_x_screw_degC", "T_z_screw_degC")
DESCRIPTION = (
    "the feed run with the X and Z axes dwelling at several positions: the ball-screw error "
    "grows with the distance from the fixed bearing (Pahk 2002)"
)


def _positions(rng: np.random.Generator, total_s: float, stops: tuple[float, ...]) -> _Steps:
    """Dwell at a random stop for 2–15 min, then move to another; drawn in continuous time."""
    s = _Steps(total_s)
    while not s.done:
        s.hold(float(rng.choice(stops)), rng.uniform(*DWELL_MIN) * 60.0)
    return s


def position_schedule(
    hours: float, seed: int = 0, sample_time_s: float = 1.0
) -> tuple[np.ndarray, np.ndarray]:
    """X and Z positions (mm from each screw's fixed bearing), one per sample."""
    check_run(hours, sample_time_s)
    rng = np.random.default_rng([seed, 2])  # [seed, 0] and [seed, 1] are the feed run's
    total_s = hours * 3600.0
    t = np.arange(round(total_s / sample_time_s) + 1) * float(sample_time_s)
    return (
        _positions(rng, total_s, X_STOPS_MM).sample(t),
        _positions(rng, total_s, Z_STOPS_MM).sample(t),
    )


def simulate_feed_positions(
    hours: float,
    seed: int = 0,
    sample_time_s: float = 1.0,
    *,
    params: MachineParameters | None = None,
) -> pd.DataFrame:
    """The ``feed`` run of ``seed`` measured at moving X/Z positions, plus :data:`POSITION_COLUMNS`.

    ``disp_x_um`` and ``disp_z_um`` replace the screw terms at the fixed
    working positions by those at the current positions (equations above);
    ``disp_y_um`` and all other columns equal the ``feed`` run's.
    """
    params = params or MachineParameters()
    frame = simulate_scenario("feed", hours, seed, sample_time_s, params=params)
    record = simulate_record(
        scenario_inputs("feed", hours, seed, sample_time_s), sample_time_s, params=params
    )
    x_mm, z_mm = position_schedule(hours, seed, sample_time_s)
    um_per_mm_per_k = ALPHA_STEEL_PER_K * 1e3
    geometry = params.geometry
    nut_x = record.temperature("nut_x")
    nut_z = record.temperature("nut_z")
    rise_x, rise_z = nut_x - nut_x[0], nut_z - nut_z[0]
    frame["disp_x_um"] += um_per_mm_per_k * (x_mm - 1e3 * geometry.x_screw_position_m) * rise_x
    frame["disp_z_um"] -= um_per_mm_per_k * (z_mm - 1e3 * geometry.z_screw_position_m) * rise_z
    frame["X_position_mm"] = x_mm
    frame["Z_position_mm"] = z_mm
    rng = np.random.default_rng([seed, 3])
    tolerance = class_a_tolerance_degc(20.0)
    for column, true in (("T_x_screw_degC", nut_x), ("T_z_screw_degC", nut_z)):
        offset = rng.uniform(-tolerance, tolerance)
        noise = rng.normal(0.0, PT100_NOISE_DEGC, size=true.shape)
        frame[column] = lag(true, SCREW_SENSOR_LAG_S, sample_time_s) + offset + noise
    return frame
