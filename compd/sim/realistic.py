"""Realistic runs of the twin: many unknown sensors and a drift no sensor sees (issue 12 item 8).

On the twin's own runs (:mod:`compd.sim.scenarios`) every sensor sits on a
node that matters, so fitting all of them is harmless. A real machine logged
by someone else is different (``../shared/data/fl_thermal_train.csv``): of its
16 temperatures several are near-duplicates of one spot, some only follow the
shop floor, one is noisy with spikes, one shows the spindle chiller's on/off
cycle, which also reaches the displacement, and the displacement creeps by
something none of them measures. Such a record invites a model with a
denominator per input to overfit: it fits the calibration run by cancelling
large sub-models of collinear sensors and mistakes the drift for the slow
response of an ambient sensor, then fails on the next speed programme.

These runs reproduce that, on the reference machine with a spindle chiller:

- one continuous record (``real_record``, 46 h): a calibration programme of
  four 8 h cycles (4 h at 3,000, 6,000, 9,000, 12,000 rpm, then 4 h standing;
  the real record's 1,250..5,000 rpm scaled to the twin's spindle), then, from
  :data:`CUT_H` = 32 h, a verify programme (4 h at 8,400 rpm, 3 h standing, a
  ladder of 1 h steps at 2,000, 5,000, 8,000 and 11,000 rpm, 3 h standing);
- ``real_calibration``: its first part, up to the cut;
- ``real_verify``: its part from the cut, as a split-off file: time from 0 and
  displacements re-zeroed at its start (the machine is not in equilibrium
  there, as on the real record).

The temperatures are ``T1`` .. ``T16`` in :data:`SENSOR_LAYOUT` order (its
comments say where each sits; a user of the file is not told). A Pt100 on a
casting reads partly the air around it, so no sensor is the temperature of
the part that moves the tool, and the model has to un-mix collinear readings:
that is where a free denominator per input finds large, cancelling sub-models
and integrators. A run longer than its programme stands at rest for the rest;
a shorter run is the head of a longer one of the same seed. The
displacements are the TCP's ``disp_x_um``, ``disp_y_um``, ``disp_z_um`` as
changes from the start, plus an unmodelled structural creep
(:func:`structural_creep_um`) and 0.1 um of probe noise, quantised to 0.01 um.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pandas as pd

from compd.sim.machine import Link, MachineParameters
from compd.sim.scenarios import check_run
from compd.sim.sensors import lag
from compd.sim.thermal import InputRecord, simulate_record

_H = 3600.0

#: Calibration programme: (spindle speed in rpm, duration in h) steps.
CALIBRATION_PROGRAMME: tuple[tuple[float, float], ...] = tuple(
    step for rpm in (3000.0, 6000.0, 9000.0, 12000.0) for step in ((rpm, 4.0), (0.0, 4.0))
)
#: Verify programme: another speed, then a speed ladder.
VERIFY_PROGRAMME: tuple[tuple[float, float], ...] = (
    (8400.0, 4.0),
    (0.0, 3.0),
    (2000.0, 1.0),
    (5000.0, 1.0),
    (8000.0, 1.0),
    (11000.0, 1.0),
    (0.0, 3.0),
)
#: The time (h) where the verify programme starts in ``real_record``.
CUT_H = sum(hours for _, hours in CALIBRATION_PROGRAMME)
RECORD_H = CUT_H + sum(hours for _, hours in VERIFY_PROGRAMME)

#: A spindle chiller on the bearing cartridge, W/K: its cycle reaches the bearings in minutes.
SPINDLE_CHILLER = Link("bearings", "coolant", 10.0)


@dataclass(frozen=True)
class SensorSpec:
    """One logged temperature: the weighted sites it reads, its lag (s) and its noise std (degC).

    ``sites`` maps node names (or ``"ambient"``, ``"coolant"``) to weights
    summing to 1; ``spikes`` marks the sensor with a loose contact.
    """

    sites: dict[str, float]
    lag_s: float
    noise_degc: float = 0.012
    spikes: bool = False


#: ``T1`` .. ``T16``, in order. Pt100s screwed onto a casting read between it and the air
#: around it (a quarter of the air's temperature here). Near-duplicates sit on one part a few cm
#: apart: they differ by offset, noise and a few per cent of a neighbouring part.
SENSOR_LAYOUT: tuple[SensorSpec, ...] = (
    SensorSpec({"headstock": 0.75, "air": 0.25}, 60.0),  # T1  headstock, left
    SensorSpec({"headstock": 0.7, "column_front": 0.05, "air": 0.25}, 60.0),  # T2  lower: near T1
    SensorSpec({"headstock": 0.68, "motor": 0.07, "air": 0.25}, 90.0),  # T3  rear: near T1
    SensorSpec({"coolant": 0.7, "bearings": 0.22, "air": 0.08}, 30.0, 0.02),  # T4  chiller return
    SensorSpec({"motor": 0.75, "ambient": 0.25}, 40.0),  # T5  spindle motor housing
    SensorSpec({"ambient": 1.0}, 600.0),  # T6  shop floor, on the guard: ambient only
    SensorSpec({"ambient": 1.0}, 2400.0),  # T7  electrical cabinet wall: ambient only
    SensorSpec({"column_front": 0.75, "air": 0.25}, 60.0),  # T8  column, guideway side
    SensorSpec({"bearings": 0.75, "air": 0.25}, 30.0),  # T9  spindle nose, front bearing
    SensorSpec({"ambient": 1.0}, 1200.0),  # T10 hall pillar behind the machine: ambient only
    SensorSpec({"bed": 0.75, "ambient": 0.25}, 120.0),  # T11 bed
    SensorSpec({"column_back": 0.75, "ambient": 0.25}, 60.0),  # T12 column back, top
    SensorSpec({"air": 1.0}, 120.0),  # T13 enclosure air, left
    SensorSpec({"column_back": 0.7, "bed": 0.05, "ambient": 0.25}, 60.0),  # T14 low: near T12
    SensorSpec({"air": 0.93, "ambient": 0.07}, 120.0),  # T15 enclosure air, door: near T13
    SensorSpec({"headstock": 0.75, "air": 0.25}, 60.0, 0.12, spikes=True),  # T16 loose contact
)
TEMPERATURE_COLUMNS = tuple(f"T{i}" for i in range(1, len(SENSOR_LAYOUT) + 1))
DISPLACEMENT_COLUMNS = ("disp_x_um", "disp_y_um", "disp_z_um")
COLUMNS = ("time_s", "spindle_speed_rpm", *TEMPERATURE_COLUMNS, *DISPLACEMENT_COLUMNS)

#: Pt100 offsets are drawn within this, degC (class A plus mounting); readings are quantised.
OFFSET_DEGC = 0.3
QUANTUM_DEGC = 0.01
DISPLACEMENT_NOISE_UM = 0.1
#: Creep multiplier per displacement column (x, y, z); see :func:`structural_creep_um`.
CREEP_SCALE = (1.0, 1.0, 2.0)
QUANTUM_UM = 0.01


def programme_speed_rpm(
    programme: tuple[tuple[float, float], ...], time_s: np.ndarray
) -> np.ndarray:
    """Spindle speed (rpm) at ``time_s`` under ``programme``; standing once it is over."""
    starts_s = np.cumsum([0.0, *(hours * _H for _, hours in programme)])
    speeds = np.array([*(rpm for rpm, _ in programme), 0.0])
    return np.asarray(speeds[np.searchsorted(starts_s, time_s, side="right") - 1])


def shop_ambient_degc(rng: np.random.Generator, time_s: np.ndarray) -> np.ndarray:
    """Shop-floor air: a day/night swing of 1-2 degC (24 h) and a slow HVAC wander of a few 0.1 degC."""
    day = rng.uniform(1.0, 2.0) * np.sin(2 * np.pi * time_s / (24 * _H) + rng.uniform(0, 2 * np.pi))
    wander = sum(
        rng.uniform(0.1, 0.3)
        * np.sin(2 * np.pi * time_s / (rng.uniform(3.0, 8.0) * _H) + rng.uniform(0, 2 * np.pi))
        for _ in range(2)
    )
    return np.asarray(rng.uniform(20.0, 24.0) + day + wander)


def chiller_degc(
    rng: np.random.Generator, ambient_degc: np.ndarray, speed_rpm: np.ndarray, time_s: np.ndarray
) -> np.ndarray:
    """Spindle chiller outlet: tracks the ambient, with an on/off sawtooth of +-0.8..1.2 degC.

    The compressor cools fast (the last 20 % of a cycle) and the load warms the
    oil slowly, so one cycle lasts 12-16 min with the spindle turning and about
    twice as long at rest. The phase is ``φ(t) = ∫ dt / P(t)``.
    """
    period_s = rng.uniform(12.0, 16.0) * 60.0 * np.where(speed_rpm > 0, 1.0, 2.0)
    steps = np.diff(time_s) / period_s[:-1]  # the period holds from each sample to the next
    phase = (rng.uniform() + np.concatenate([[0.0], np.cumsum(steps)])) % 1.0
    rise = 0.8
    saw = np.where(phase < rise, phase / rise, (1.0 - phase) / (1.0 - rise)) * 2.0 - 1.0
    return np.asarray(ambient_degc - 0.5 + rng.uniform(0.8, 1.2) * saw)


def structural_creep_um(rng: np.random.Generator, time_s: np.ndarray) -> np.ndarray:
    """Displacement (um, ``(3, samples)``) that no sensor sees: settling and a creep of 0.05-0.4 um/h.

    Per axis ``c(t) = ±m (r t + s (1 − e^{−t/τ}))`` with ``r`` of 0.05-0.2 um/h,
    ``s`` of 0.5-2 um and ``τ`` of 10-30 h: bolted joints and the foundation
    settling, monotone, and still going on through the verify run. ``m`` is
    :data:`CREEP_SCALE`: twice as much in z, whose loop (bed, column,
    headstock) is the longest.
    """
    hours = time_s / _H
    creep = [
        scale
        * rng.choice([-1.0, 1.0])
        * (
            rng.uniform(0.05, 0.2) * hours
            + rng.uniform(0.5, 2.0) * -np.expm1(-hours / rng.uniform(10.0, 30.0))
        )
        for scale in CREEP_SCALE
    ]
    return np.asarray(creep)


def _spikes_degc(rng: np.random.Generator, time_s: np.ndarray) -> np.ndarray:
    """A loose contact: about one spike an hour of +0.5..3 degC decaying within a few minutes."""
    out = np.zeros_like(time_s)
    event_s = rng.uniform(0.0, 1.0) * _H
    while event_s < time_s[-1]:
        after = time_s >= event_s
        out[after] += rng.uniform(0.5, 3.0) * np.exp(-(time_s[after] - event_s) / 90.0)
        event_s += rng.exponential(_H)
    return out


def _quantised(x: np.ndarray, quantum: float) -> np.ndarray:
    return np.asarray(np.round(x / quantum) * quantum)


def _read(
    spec: SensorSpec, true_degc: np.ndarray, time_s: np.ndarray, seed: int, k: int
) -> np.ndarray:
    """Sensor ``k``'s logged reading: lag, Pt100 offset, noise, spikes if it has them, quantised."""
    rng = np.random.default_rng([seed, 1, k])
    reading = lag(true_degc, spec.lag_s, time_s[1] - time_s[0]) + rng.uniform(
        -OFFSET_DEGC, OFFSET_DEGC
    )
    reading = reading + rng.normal(0.0, spec.noise_degc, size=time_s.shape)
    if spec.spikes:
        reading = reading + _spikes_degc(np.random.default_rng([seed, 4]), time_s)
    return _quantised(reading, QUANTUM_DEGC)


def chilled(params: MachineParameters) -> MachineParameters:
    """``params`` with the spindle chiller on the bearing cartridge."""
    return dataclasses.replace(params, links=(*params.links, SPINDLE_CHILLER))


def simulate_real_record(
    hours: float,
    seed: int = 0,
    sample_time_s: float = 15.0,
    *,
    params: MachineParameters | None = None,
) -> pd.DataFrame:
    """The ``real_record`` run over ``hours`` (its programme lasts :data:`RECORD_H` h): :data:`COLUMNS`.

    The machine (``params`` with :data:`SPINDLE_CHILLER`) starts at rest in
    equilibrium with the first ambient and chiller temperatures. The schedule
    uses ``[seed, 0]``; the sensors, the creep and the probes streams of their own.
    """
    check_run(hours, sample_time_s)
    machine = chilled(params or MachineParameters())
    time_s = np.arange(round(hours * _H / sample_time_s) + 1) * float(sample_time_s)
    rng = np.random.default_rng([seed, 0])
    speed = programme_speed_rpm(CALIBRATION_PROGRAMME + VERIFY_PROGRAMME, time_s)
    ambient = shop_ambient_degc(rng, time_s)
    coolant = chiller_degc(rng, ambient, speed, time_s)
    zero = np.zeros_like(time_s)
    inputs = InputRecord(ambient, coolant, speed, zero, zero, zero, zero)
    record = simulate_record(inputs, sample_time_s, params=machine)
    boundary = {"ambient": ambient, "coolant": coolant}

    def site(name: str) -> np.ndarray:
        return boundary[name] if name in boundary else record.temperature(name)

    columns: dict[str, np.ndarray] = {"time_s": time_s, "spindle_speed_rpm": speed}
    # One random stream per sensor and probe, so a shorter run is the head of a longer one.
    for k, (column, spec) in enumerate(zip(TEMPERATURE_COLUMNS, SENSOR_LAYOUT, strict=True)):
        true = np.asarray(sum(weight * site(name) for name, weight in spec.sites.items()))
        columns[column] = _read(spec, true, time_s, seed, k)
    creep = structural_creep_um(np.random.default_rng([seed, 2]), time_s)
    for k, column in enumerate(DISPLACEMENT_COLUMNS):
        noise = np.random.default_rng([seed, 3, k]).normal(0.0, DISPLACEMENT_NOISE_UM, time_s.size)
        columns[column] = _quantised(record.displacement_um[k] + creep[k] + noise, QUANTUM_UM)
    return pd.DataFrame(columns)


def simulate_real_calibration(
    hours: float,
    seed: int = 0,
    sample_time_s: float = 15.0,
    *,
    params: MachineParameters | None = None,
) -> pd.DataFrame:
    """``real_calibration``: the first ``hours`` of ``real_record`` (its programme is :data:`CUT_H` h)."""
    return simulate_real_record(hours, seed, sample_time_s, params=params)


def simulate_real_verify(
    hours: float,
    seed: int = 0,
    sample_time_s: float = 15.0,
    *,
    params: MachineParameters | None = None,
) -> pd.DataFrame:
    """``real_verify``: ``real_record`` from :data:`CUT_H` for ``hours``, split off as its own file.

    Time restarts at 0 and the displacements are re-zeroed at the cut (a
    split-off log's contract); the temperatures are as logged.
    """
    check_run(hours, sample_time_s)
    whole = simulate_real_record(CUT_H + hours, seed, sample_time_s, params=params)
    part = whole[whole["time_s"] >= CUT_H * _H].reset_index(drop=True)
    part["time_s"] = part["time_s"] - CUT_H * _H
    for column in DISPLACEMENT_COLUMNS:
        part[column] = _quantised(part[column] - part[column].iloc[0], QUANTUM_UM)
    return part


#: Scenario name -> (generator ``f(hours, seed, sample_time_s, params=...)``, description).
REALISTIC_SCENARIOS: dict[str, tuple[Callable[..., pd.DataFrame], str]] = {
    "real_calibration": (
        simulate_real_calibration,
        f"realistic 16-sensor run (T1..T16: near-duplicates, ambient-only, spiky, chiller "
        f"cycle; unmodelled creep): four 8 h heat/cool cycles, {CUT_H:g} h",
    ),
    "real_verify": (
        simulate_real_verify,
        "the realistic run after the calibration: 8400 rpm cycle then a speed ladder, "
        f"{RECORD_H - CUT_H:g} h, split off (re-zeroed)",
    ),
    "real_record": (
        simulate_real_record,
        f"real_calibration then real_verify as one {RECORD_H:g} h record; the verify "
        f"programme starts at {CUT_H:g} h",
    ),
}
