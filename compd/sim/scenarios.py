"""Test runs of the twin: ISO 230-3 style calibration, speed spectrum, and hidden-effect runs.

Each scenario is a recipe for the machine's inputs, randomised by a seed:
the same seed gives the same run; another seed a different run with the same
statistics. Schedules are drawn in continuous time, so one seed gives the same
run at any sample time. The hidden-effect scenarios (``cutting``, ``feed``,
``door``, ``coolant``) vary exactly one effect over production-like spindle
speeds and keep everything else as in ``calibration`` (door shut, no feed, no
cutting, constant coolant), so each effect can be identified on its own;
``cutting_coolant`` hides two at once, ``shift`` mixes them all as in a real
8-hour shift.

Where each hidden effect shows, and why no temperature sensor sees it:

=========  ======================  =============  ================================================
scenario   signal                  axis           path (unsensed nodes)
=========  ======================  =============  ================================================
cutting    ``spindle_power_kw``    ``disp_z_um``  workpiece/table growth, tool heat into the shaft
feed       ``feed_z_mm_per_min``   ``disp_z_um``  Z ball-screw nut and shaft
feed       ``feed_x_mm_per_min``   ``disp_x_um``  X ball-screw nut and shaft
door       ``door_open``           ``disp_z_um``  enclosure air -> Z screw, shaft, table
coolant    ``T_coolant_degC``      ``disp_z_um``  table and workpiece in the coolant flood
=========  ======================  =============  ================================================
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pandas as pd

from compd.errors import ScenarioError
from compd.sim.machine import MachineParameters
from compd.sim.sensors import (
    COLUMNS,
    TEMPERATURE_SENSORS,
    SensorSet,
    read_displacements,
    read_temperatures,
    reported_power_kw,
)
from compd.sim.thermal import InputRecord, simulate_record

MAX_HOURS = 24.0 * 14
MAX_SAMPLE_TIME_S = 60.0
_MIN = 60.0


class _Steps:
    """A piecewise-constant schedule drawn in continuous time: ``value[i]`` from ``start_s[i]``."""

    def __init__(self, total_s: float, initial: float = 0.0) -> None:
        self.total_s = total_s
        self.start_s = [0.0]
        self.value = [initial]
        self.now_s = 0.0

    def hold(self, value: float, duration_s: float) -> None:
        self.start_s.append(self.now_s)
        self.value.append(value)
        self.now_s += duration_s

    @property
    def done(self) -> bool:
        return self.now_s >= self.total_s

    def sample(self, time_s: np.ndarray) -> np.ndarray:
        idx = np.searchsorted(np.asarray(self.start_s), time_s, side="right") - 1
        return np.asarray(self.value, dtype=float)[idx]


def _ambient(rng: np.random.Generator, t: np.ndarray) -> np.ndarray:
    """Shop-floor temperature: 19–23 degC, a daily-ish swing of ±1–2 degC, and HVAC wander.

    The wander (three sines of 0.3–0.7 degC, periods 1–4 h) makes the ambient
    move independently of the machine within a few hours.
    """
    t0 = rng.uniform(19.0, 23.0)
    amp = rng.uniform(1.0, 2.0)
    period_s = rng.uniform(16.0, 30.0) * 3600
    phase = rng.uniform(0, 2 * np.pi)
    wander = np.zeros_like(t)
    for _ in range(3):
        wander += rng.uniform(0.3, 0.7) * np.sin(
            2 * np.pi * t / (rng.uniform(1.0, 4.0) * 3600) + rng.uniform(0, 2 * np.pi)
        )
    return np.asarray(t0 + amp * np.sin(2 * np.pi * t / period_s + phase) + wander)


def _calibration_speeds(rng: np.random.Generator, total_s: float) -> _Steps:
    """ISO 230-3 heating at constant speeds (40–90 min each), each followed by cooling at rest.

    Five levels in random order span the speed range within about 9 h, so an
    8-hour calibration already shows the model most of it.
    """
    s = _Steps(total_s)
    while not s.done:
        for level in rng.permutation([2000.0, 4500.0, 7000.0, 9500.0, 12000.0]):
            s.hold(level, rng.uniform(40, 90) * _MIN)
            s.hold(0.0, rng.uniform(25, 60) * _MIN)
    return s


def _spectrum_speeds(rng: np.random.Generator, total_s: float) -> _Steps:
    """ISO 230-3 speed spectrum: a new speed every 20–60 min, stops included."""
    s = _Steps(total_s)
    while not s.done:
        level = 0.0 if rng.random() < 0.2 else float(rng.integers(2, 25) * 500)
        s.hold(level, rng.uniform(20, 60) * _MIN)
    return s


def _production_speeds(rng: np.random.Generator, total_s: float) -> _Steps:
    """Production: a new speed every 2–20 min (1,000–10,000 rpm), short stops for tool changes."""
    s = _Steps(total_s)
    while not s.done:
        if rng.random() < 0.15:
            s.hold(0.0, rng.uniform(1, 5) * _MIN)
        else:
            s.hold(float(rng.integers(2, 21) * 500), rng.uniform(2, 20) * _MIN)
    return s


def _cutting_power(rng: np.random.Generator, total_s: float) -> _Steps:
    """Heavy cutting phases (15–60 min of 1–5 min cuts at 2–10 kW) between 20–90 min without."""
    s = _Steps(total_s)
    while not s.done:
        s.hold(0.0, rng.uniform(20, 90) * _MIN)
        phase_end = s.now_s + rng.uniform(15, 60) * _MIN
        while s.now_s < phase_end:
            s.hold(rng.uniform(2.0, 10.0), rng.uniform(1, 5) * _MIN)
            s.hold(0.0, rng.uniform(5, 30))  # tool retract / next cut
    return s


def _feed(rng: np.random.Generator, total_s: float) -> tuple[_Steps, _Steps]:
    """Long phases (30–120 min) of rapid X/Z motion: moves of 2–20 s at up to 24 m/min."""
    fx, fz = _Steps(total_s), _Steps(total_s)
    while not fx.done:
        rest = rng.uniform(20, 60) * _MIN
        fx.hold(0.0, rest)
        fz.hold(0.0, rest)
        phase_end = fx.now_s + rng.uniform(30, 120) * _MIN
        while fx.now_s < phase_end:
            move_s = rng.uniform(2, 20)
            fx.hold(0.0 if rng.random() < 0.3 else rng.uniform(2000, 24000), move_s)
            fz.hold(0.0 if rng.random() < 0.3 else rng.uniform(2000, 24000), move_s)
    return fx, fz


def _door(rng: np.random.Generator, total_s: float) -> _Steps:
    """Door openings of 3–10 min every 10–40 min (loading, measuring, chip clearing)."""
    s = _Steps(total_s)
    while not s.done:
        s.hold(0.0, rng.uniform(10, 40) * _MIN)
        s.hold(1.0, rng.uniform(3, 10) * _MIN)
    return s


def _coolant_drift(rng: np.random.Generator, t: np.ndarray, base_degc: float) -> np.ndarray:
    """A failing chiller: the coolant warms by 3–6 degC over 1–2.5 h, holds, then recovers."""
    times, values = [0.0], [base_degc]
    while times[-1] < t[-1]:
        for duration_min, rise in (
            (rng.uniform(20, 60), 0.0),
            (rng.uniform(60, 150), rng.uniform(3.0, 6.0)),
            (rng.uniform(20, 60), None),
            (rng.uniform(30, 90), 0.0),
        ):
            times.append(times[-1] + duration_min * _MIN)
            values.append(values[-1] if rise is None else base_degc + rise)
    return np.asarray(np.interp(t, times, values))


@dataclass(frozen=True)
class _Effects:
    cutting: bool = False
    feed: bool = False
    door: bool = False
    coolant: bool = False
    speeds: Callable[[np.random.Generator, float], _Steps] = _production_speeds


SCENARIOS: dict[str, tuple[_Effects, str]] = {
    "calibration": (
        _Effects(speeds=_calibration_speeds),
        "ISO 230-3 heating at constant speeds and cooling, ambient swing, nothing else",
    ),
    "speed_spectrum": (_Effects(speeds=_spectrum_speeds), "ISO 230-3 speed spectrum"),
    "production": (
        _Effects(),
        "production speeds with light (air) cutting, door shut: no hidden effect",
    ),
    "cutting": (_Effects(cutting=True), "production speeds with heavy cutting (2-10 kW)"),
    "feed": (_Effects(feed=True), "production speeds with long phases of rapid X/Z motion"),
    "door": (_Effects(door=True), "production speeds with door openings"),
    "coolant": (_Effects(coolant=True), "production speeds with the coolant drifting by 3-6 degC"),
    "cutting_coolant": (
        _Effects(cutting=True, coolant=True),
        "heavy cutting and a drifting coolant at once: two hidden effects",
    ),
    "shift": (
        _Effects(cutting=True, feed=True, door=True, coolant=True),
        "an 8-hour production shift mixing all effects",
    ),
}


def scenario_inputs(
    name: str, hours: float, seed: int = 0, sample_time_s: float = 1.0
) -> InputRecord:
    """The machine inputs of scenario ``name``, one sample every ``sample_time_s`` over ``hours``."""
    effects = _scenario(name)
    check_run(hours, sample_time_s)
    rng = np.random.default_rng([seed, 0])  # the schedule; sensors use [seed, 1]
    total_s = hours * 3600.0
    t = np.arange(round(total_s / sample_time_s) + 1) * float(sample_time_s)
    ambient = _ambient(rng, t)
    coolant_base = float(ambient[0] + rng.uniform(-0.5, 1.0))
    speed = effects.speeds(rng, total_s).sample(t)
    zero = np.zeros_like(t)
    cutting = _cutting_power(rng, total_s).sample(t) * (speed > 0) if effects.cutting else zero
    if effects.feed:
        fx, fz = _feed(rng, total_s)
        feed_x, feed_z = fx.sample(t), fz.sample(t)
    else:
        feed_x = feed_z = zero
    door = _door(rng, total_s).sample(t) if effects.door else zero
    coolant = (
        _coolant_drift(rng, t, coolant_base) if effects.coolant else np.full_like(t, coolant_base)
    )
    return InputRecord(ambient, coolant, speed, cutting, feed_x, feed_z, door)


def simulate_scenario(
    name: str,
    hours: float,
    seed: int = 0,
    sample_time_s: float = 1.0,
    *,
    params: MachineParameters | None = None,
) -> pd.DataFrame:
    """A logged run of scenario ``name``: the :data:`COLUMNS`, one row per sample.

    Temperatures and displacements are sensor readings (lag, class-A offset,
    noise; see :mod:`compd.sim.sensors`). The machine starts cold, at rest, in
    equilibrium with the first ambient and coolant temperatures, so the
    displacements start at zero (± noise).
    """
    params = params or MachineParameters()
    inputs = scenario_inputs(name, hours, seed, sample_time_s)
    record = simulate_record(inputs, sample_time_s, params=params)
    rng = np.random.default_rng([seed, 1])
    sensors = SensorSet.draw(rng)
    sites = {
        col: (
            inputs.T_coolant_degC
            if site == "coolant"
            else inputs.T_ambient_degC
            if site == "ambient"
            else record.temperature(site)
        )
        for col, site in TEMPERATURE_SENSORS.items()
    }
    columns: dict[str, np.ndarray] = {
        "time_s": np.arange(len(inputs)) * float(sample_time_s),
        "spindle_speed_rpm": inputs.spindle_speed_rpm,
        "spindle_power_kw": reported_power_kw(
            params, inputs.spindle_speed_rpm, inputs.cutting_power_kw, rng
        ),
        "feed_x_mm_per_min": inputs.feed_x_mm_per_min,
        "feed_z_mm_per_min": inputs.feed_z_mm_per_min,
        "door_open": inputs.door_open.astype(int),
        **read_temperatures(sites, sensors, sample_time_s, rng),
        **read_displacements(record.displacement_um, rng),
    }
    return pd.DataFrame({name: columns[name] for name in COLUMNS})


def _scenario(name: str) -> _Effects:
    try:
        return SCENARIOS[name][0]
    except KeyError:
        raise ScenarioError(
            f"there is no scenario {name!r}; choose one of {', '.join(SCENARIOS)}"
        ) from None


def check_run(hours: float, sample_time_s: float) -> None:
    """Refuse a run length or sample time the twin does not generate (a :class:`ScenarioError`)."""
    if not (np.isfinite(hours) and 0 < hours <= MAX_HOURS):
        raise ScenarioError(f"hours must be above 0 and at most {MAX_HOURS:g}, not {hours}")
    if not (np.isfinite(sample_time_s) and 0 < sample_time_s <= MAX_SAMPLE_TIME_S):
        raise ScenarioError(
            f"sample_time_s must be above 0 and at most {MAX_SAMPLE_TIME_S:g} s, not {sample_time_s}"
        )
    if hours * 3600 < 2 * sample_time_s:
        raise ScenarioError(f"{hours} h is shorter than two samples of {sample_time_s} s")
