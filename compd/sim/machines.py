"""Random machines for tests and benchmarks: many twins, each logged as a new user's files (issue 20 item 4).

:func:`random_machine` draws, from one seed, a machine of the realistic twin
(:mod:`compd.sim.realistic`: a reference, spindle-head or long-nose variant
with every capacity, conductance, heat law and lever arm scattered by tens of
per cent; a spindle chiller on some), how it was logged and what it was run
through:

- 4-24 temperature sensors: some on parts that move the tool (mixed with the
  air around them), near-duplicates of those (a few cm apart: another
  offset, noise and a few per cent of a neighbouring part), ambient-only
  ones with long lags, and some that see nothing useful (a hydraulic unit or
  a cabinet with its own slow cycle); now and then one with a loose contact;
- a sample time of 15 s to 5 min; temperatures as absolute readings or as
  rises from each file's start (a logger that zeroes at each run, as real
  record C); Pt100 offsets, noise and 0.01 degC quantisation;
- a calibration of one continuous record (3-48 h, at least 70 samples) or of
  3-6 warm-up runs (2-8 h each, at least 70 samples) with 1-16 h standing
  between them (a run may start still warm), each run one file;
- verify data on a *different* programme (:mod:`compd.sim.programmes`): the
  record's later part split off as its own file (time from 0, displacement
  re-zeroed, machine not in equilibrium), or 1-2 later warm-up runs;
- sometimes heavy cutting or door openings (heat into the table, shaft and
  enclosure air that no sensor sees: :mod:`compd.sim.scenarios`);
- one displacement axis scaled to 2-100 um peak to peak over the
  calibration, probe noise of 0.02-0.2 um and 0.01 or 0.1 um quantisation,
  and sometimes an unmodelled creep of 5-25 % of that.

The twin is simulated at the sample time or a whole fraction of it no
longer than 60 s and read at the sample time; a case takes well under a
second and nothing is cached.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from compd.sim.machine import NODES, MachineParameters
from compd.sim.programmes import PROGRAMMES, draw_programme, speed_on_grid
from compd.sim.realistic import SPINDLE_CHILLER, chiller_degc, shop_ambient_degc
from compd.sim.sensorlayout import SensorPlan, draw_sensors, read_sensors
from compd.sim.sensors import lag
from compd.sim.thermal import InputRecord, simulate_record
from compd.sim.variants import VARIANTS

_H = 3600.0
#: Sample times drawn from, s.
SAMPLE_TIMES_S = (15.0, 20.0, 30.0, 60.0, 90.0, 120.0, 180.0, 240.0, 300.0)
#: The twin is integrated at no more than this step, s (then read at the sample time).
MAX_STEP_S = 60.0
MIN_SAMPLES = 70
MAX_RECORD_H = 48.0
AMPLITUDE_UM = (2.0, 100.0)
AXES = ("z", "y", "x")
TIME_COLUMN = "time_s"
SPEED_COLUMN = "spindle_speed_rpm"


@dataclass(frozen=True)
class MachineCase:
    """One random machine's files as a new user has them, and how it was drawn."""

    seed: int
    description: str  # one line: sensors, sample time, length, runs, input kind, amplitude
    sample_time_s: float
    calibration: tuple[pd.DataFrame, ...]  # one record or 3-6 warm-up runs (each an experiment)
    verify: tuple[
        pd.DataFrame, ...
    ]  # later/unseen data, a different programme from the calibration's
    inputs: tuple[str, ...]  # the temperature columns a new user would pass (all of them)
    output: str  # displacement column, um
    #: What was drawn, for tests and for reading a benchmark's worst cases.
    facts: dict[str, object] = dataclasses.field(default_factory=dict, compare=False)
    #: The whole timeline as one log from the calibration's start (between warm-up runs too,
    #: the machine standing), zeroed there; and the time the verify programme starts in it (s).
    #: How the daemon meets that programme: running on from the calibration, its state
    #: carried (``compd compare --data log.csv --from CUT``).
    log: pd.DataFrame | None = dataclasses.field(default=None, compare=False)
    cut_s: float | None = None
    #: Where each file (calibration, then verify) starts in the log, s.
    file_starts_s: tuple[float, ...] = ()


def _scatter(rng: np.random.Generator, value: float, spread: float) -> float:
    """``value`` times a log-uniform factor within ``1/spread .. spread``."""
    return float(value * math.exp(rng.uniform(-math.log(spread), math.log(spread))))


def random_parameters(rng: np.random.Generator) -> tuple[MachineParameters, str]:
    """A variant of the twin with every capacity, conductance, heat law and lever arm scattered."""
    variant = str(rng.choice(list(VARIANTS)))
    base = VARIANTS[variant][0]
    capacity = tuple(_scatter(rng, c, 1.6) for c in base.capacity_j_per_k)
    links = tuple(
        dataclasses.replace(
            link, g0=_scatter(rng, link.g0, 1.4), g_speed=_scatter(rng, link.g_speed, 1.4)
        )
        for link in base.links
    )
    heat = dataclasses.replace(
        base.heat,
        k_bearing_w=_scatter(rng, base.heat.k_bearing_w, 2.0),
        bearing_to_shaft=rng.uniform(0.3, 0.75),
        k_motor0_w=_scatter(rng, base.heat.k_motor0_w, 1.5),
        k_motor1_w=_scatter(rng, base.heat.k_motor1_w, 1.5),
        q_aux_w=_scatter(rng, base.heat.q_aux_w, 1.5),
    )
    geometry = dataclasses.replace(
        base.geometry,
        **{
            f.name: _scatter(rng, getattr(base.geometry, f.name), 1.4)
            for f in dataclasses.fields(base.geometry)
        },
    )
    params = MachineParameters(capacity, links, heat, geometry)
    chilled = bool(rng.random() < 0.4)
    if chilled:
        params = dataclasses.replace(params, links=(*params.links, SPINDLE_CHILLER))
    return params, variant + (" + chiller" if chilled else "")


@dataclass(frozen=True)
class _Plan:
    """The timeline: files as (start_s, stop_s) on it, which are calibration, and the programmes."""

    sample_time_s: float
    files: tuple[tuple[float, float], ...]
    n_calibration: int
    speed_rpm_of: Callable[[np.ndarray], np.ndarray]
    total_s: float
    calibration_kind: str
    verify_kind: str
    continuous: bool


def _hours_at_least(rng: np.random.Generator, low_h: float, high_h: float, ts: float) -> float:
    """A length of ``low_h..high_h`` (log-uniform) with at least :data:`MIN_SAMPLES` samples."""
    low_h = max(low_h, MIN_SAMPLES * ts / _H)
    high_h = max(high_h, low_h)
    hours = math.exp(rng.uniform(math.log(low_h), math.log(high_h)))
    return max(MIN_SAMPLES, round(hours * _H / ts)) * ts / _H


def _plan(
    rng: np.random.Generator,
    ts: float,
    max_rpm: float,
    calibration_scale: float = 1.0,
    longer: np.random.Generator | None = None,
) -> _Plan:
    kinds = list(PROGRAMMES)
    calibration_kind = str(rng.choice(kinds))
    verify_kind = str(rng.choice([k for k in kinds if k != calibration_kind]))
    continuous = bool(rng.random() < 0.5)
    segments: list[tuple[float, float, list[tuple[float, float]]]] = []  # start, stop, steps
    if continuous:
        cal_h = _hours_at_least(rng, 3.0, MAX_RECORD_H, ts)
        ver_h = _hours_at_least(rng, 3.0, max(3.0, rng.uniform(0.3, 0.7) * cal_h), ts)
        cal_s, ver_s = cal_h * _H, ver_h * _H
        steps = draw_programme(calibration_kind, rng, cal_s, max_rpm)
        if calibration_scale != 1.0 and longer is not None:
            # A longer calibration of the same kind from its own stream: the machine, its
            # sensors and the verify programme are drawn as at scale 1.
            cal_s = max(1, round(cal_s * calibration_scale / ts)) * ts
            steps = draw_programme(calibration_kind, longer, cal_s, max_rpm)
        segments.append((0.0, cal_s, steps))
        segments.append((cal_s, cal_s + ver_s, draw_programme(verify_kind, rng, ver_s, max_rpm)))
        n_calibration = 1
    else:
        n_calibration = int(rng.integers(3, 7))
        n_verify = int(rng.integers(1, 3))
        # More warm-up runs of the same kind from their own stream, after the drawn ones.
        extra = round(n_calibration * (calibration_scale - 1.0)) if longer is not None else 0
        now_s = 0.0

        def run(kind: str, draws: np.random.Generator) -> None:
            nonlocal now_s
            run_s = _hours_at_least(draws, 2.0, 8.0, ts) * _H
            segments.append((now_s, now_s + run_s, draw_programme(kind, draws, run_s, max_rpm)))
            # Standing between runs: overnight, or a short break (the next run starts warm).
            now_s = round((now_s + run_s + draws.uniform(1.0, 16.0) * _H) / ts) * ts

        for k in range(n_calibration + n_verify):
            run(calibration_kind if k < n_calibration else verify_kind, rng)
            if k == n_calibration - 1 and longer is not None:
                for _ in range(max(0, extra)):
                    run(calibration_kind, longer)
        n_calibration += max(0, extra)
    # Each segment's steps are cut at its end: the programme is what ran during the file.
    starts = np.array([s for s, _, _ in segments])
    stops = np.array([e for _, e, _ in segments])

    def speed_rpm(time_s: np.ndarray) -> np.ndarray:
        out = np.zeros_like(time_s)
        for start, stop, steps in segments:
            inside = (time_s >= start) & (time_s < stop)
            out[inside] = speed_on_grid(steps, time_s[inside], start)
        return out

    return _Plan(
        ts,
        tuple(zip(starts.tolist(), stops.tolist(), strict=True)),
        n_calibration,
        speed_rpm,
        float(stops[-1]),
        calibration_kind,
        verify_kind,
        continuous,
    )


def _creep_um(rng: np.random.Generator, time_s: np.ndarray, size_um: float) -> np.ndarray:
    """Unmodelled creep of ``size_um`` over the timeline: settling plus a steady rate, monotone."""
    hours = time_s / _H
    shape = 0.5 * hours / hours[-1] - 0.5 * np.expm1(-hours / rng.uniform(5.0, 30.0))
    return np.asarray(rng.choice([-1.0, 1.0]) * size_um * shape / max(float(shape[-1]), 1e-9))


def _blocks(
    rng: np.random.Generator,
    time_s: np.ndarray,
    on_s: tuple[float, float],
    off_s: tuple[float, float],
) -> np.ndarray:
    """1 in blocks of ``on_s`` (uniform range, s) separated by ``off_s``, 0 elsewhere; a level per block."""
    out = np.zeros_like(time_s)
    now_s = rng.uniform(*off_s)
    while now_s < time_s[-1]:
        length_s = rng.uniform(*on_s)
        out[(time_s >= now_s) & (time_s < now_s + length_s)] = rng.uniform(0.3, 1.0)
        now_s += length_s + rng.uniform(*off_s)
    return out


def _hidden_effects(
    rng: np.random.Generator, time_s: np.ndarray, speed_rpm: np.ndarray
) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Sometimes heavy cutting (1.5-5 kW in 5-30 min phases) and door openings: heat no sensor sees."""
    cutting_kw, door, effects = np.zeros_like(time_s), np.zeros_like(time_s), []
    if rng.random() < 0.2:
        cutting_kw = 5.0 * _blocks(rng, time_s, (300.0, 1800.0), (600.0, 5400.0)) * (speed_rpm > 0)
        effects.append("cutting")
    if rng.random() < 0.2:
        door = (_blocks(rng, time_s, (180.0, 600.0), (1200.0, 5400.0)) > 0).astype(float)
        effects.append("door")
    return cutting_kw, door, effects


def random_machine(seed: int, *, calibration_scale: float = 1.0) -> MachineCase:
    """The machine, logging and programmes of ``seed``: the same seed gives the same case.

    ``calibration_scale``: a one-record machine's calibration that many times
    as long (the same programme kind, drawn afresh), or that many times as
    many warm-up runs (the drawn ones first, then more of the same kind);
    everything else drawn as at 1: what a longer calibration buys the same
    machine (``benchmarks/bench_machines.py --calibration-scale``).
    """
    rng = np.random.default_rng([seed, 20, 4])
    params, variant = random_parameters(rng)
    ts = float(rng.choice(SAMPLE_TIMES_S))
    max_rpm = float(rng.choice([8000.0, 10000.0, 12000.0, 15000.0]))
    plan = _plan(rng, ts, max_rpm, calibration_scale, np.random.default_rng([seed, 20, 9]))
    substeps = math.ceil(ts / MAX_STEP_S)
    step_s = ts / substeps
    time_s = np.arange(round(plan.total_s / step_s) + 1) * step_s
    speed = plan.speed_rpm_of(time_s)
    ambient = shop_ambient_degc(rng, time_s)
    if rng.random() < 0.3:  # a climate-controlled hall: a tenth of the swing
        ambient = ambient[0] + 0.1 * (ambient - ambient[0])
    chilled = "chiller" in variant
    coolant = (
        chiller_degc(rng, ambient, speed, time_s)
        if chilled
        else lag(ambient, 2 * _H, step_s) + rng.uniform(0.0, 1.5)
    )
    zero = np.zeros_like(time_s)
    cutting_kw, door, effects = _hidden_effects(np.random.default_rng([seed, 20, 7]), time_s, speed)
    record = simulate_record(
        InputRecord(ambient, coolant, speed, cutting_kw, zero, zero, door), step_s, params=params
    )
    read = slice(None, None, substeps)
    time_s, speed = time_s[read], speed[read]
    sites = {name: record.temperature(name)[read] for name in NODES}
    sites["ambient"], sites["coolant"] = ambient[read], coolant[read]

    plan_sensors: SensorPlan = draw_sensors(rng, int(rng.integers(4, 25)))
    temperatures = read_sensors(plan_sensors, sites, time_s, seed)

    axis = str(rng.choice(AXES, p=[0.5, 0.35, 0.15]))
    true_um = record.displacement_um[{"x": 0, "y": 1, "z": 2}[axis]][read]
    files = [(round(a / ts), round(b / ts)) for a, b in plan.files]
    first, stop = files[0][0], files[plan.n_calibration - 1][1]
    span = float(np.ptp(true_um[first : stop + 1])) or 1.0
    amplitude_um = math.exp(rng.uniform(*np.log(AMPLITUDE_UM)))
    true_um = true_um * amplitude_um / span
    creep = rng.random() < 0.3
    if creep:
        true_um = true_um + _creep_um(rng, time_s, rng.uniform(0.05, 0.25) * amplitude_um)
    noise_um = rng.uniform(0.02, 0.2)
    quantum_um = float(rng.choice([0.01, 0.01, 0.1]))
    rises = bool(rng.random() < 0.4)
    with_speed = bool(rng.random() < 0.5)
    output = f"disp_{axis}_um"
    probe = np.random.default_rng([seed, 20, 5])
    # The probe's noise per logged sample: each file's own draws (a sample two files share, the
    # cut, is read once per file); the log both files were cut from reads the files' samples.
    noise = [probe.normal(0.0, noise_um, b + 1 - a) for a, b in files]

    def frame(a: int, b: int, probe_noise: np.ndarray) -> pd.DataFrame:
        """Samples ``a .. b`` as a log that started at ``a``: zeroed there (temperatures if rises)."""
        part = slice(a, b + 1)
        columns: dict[str, np.ndarray] = {TIME_COLUMN: time_s[part] - time_s[a]}
        if with_speed:
            columns[SPEED_COLUMN] = speed[part]
        for name, values in temperatures.items():
            values = values[part]
            columns[name] = _quantised(values - values[0] if rises else values, 0.01)
        columns[output] = _quantised(true_um[part] - true_um[a] + probe_noise, quantum_um)
        return pd.DataFrame(columns)

    frames = [frame(a, b, n) for (a, b), n in zip(files, noise, strict=True)]
    # The whole timeline as one log, logged between the files too (the machine standing
    # between warm-up runs): each file's samples read as in the file, the rest freshly.
    first = files[0][0]
    log_noise = np.random.default_rng([seed, 20, 6]).normal(0.0, noise_um, files[-1][1] + 1 - first)
    for (a, b), n in reversed(list(zip(files, noise, strict=True))):  # a shared cut: the earlier's
        log_noise[a - first : b + 1 - first] = n
    log = frame(first, files[-1][1], log_noise)
    calibration, verify = frames[: plan.n_calibration], frames[plan.n_calibration :]
    runs = (
        f"one {len(calibration[0]) * ts / _H:.1f} h record"
        if plan.continuous
        else f"{len(calibration)} warm-up runs of {_mean_h(calibration, ts):.1f} h"
    )
    counts = plan_sensors.counts()
    description = (
        f"seed {seed}: {len(temperatures)} sensors ({counts['duplicate']} near-duplicate, "
        f"{counts['ambient']} ambient-only, {counts['unrelated']} unrelated), Ts {ts:g} s, "
        f"{runs} ({plan.calibration_kind}) -> verify {len(verify)} file(s) of "
        f"{_mean_h(verify, ts):.1f} h ({plan.verify_kind}), "
        f"{'rises' if rises else 'absolute'}, {amplitude_um:.1f} um {axis}"
        f"{', creep' if creep else ''}{''.join(', ' + e for e in effects)}, {variant}"
    )
    facts: dict[str, object] = {
        "variant": variant,
        "continuous": plan.continuous,
        "calibration_kind": plan.calibration_kind,
        "verify_kind": plan.verify_kind,
        "rises": rises,
        "amplitude_um": amplitude_um,
        "creep": creep,
        "effects": effects,
        "axis": axis,
        "with_speed": with_speed,
        "kinds": plan_sensors.kinds,
        "noise_um": noise_um,
        "quantum_um": quantum_um,
    }
    return MachineCase(
        seed,
        description,
        ts,
        tuple(calibration),
        tuple(verify),
        tuple(temperatures),
        output,
        facts,
        log,
        float(time_s[files[plan.n_calibration][0]] - time_s[first]),
        tuple(float(time_s[a] - time_s[first]) for a, _ in files),
    )


def _mean_h(frames: list[pd.DataFrame], ts: float) -> float:
    return float(np.mean([(len(f) - 1) * ts / _H for f in frames]))


def _quantised(x: np.ndarray, quantum: float) -> np.ndarray:
    return np.asarray(np.round(x / quantum) * quantum)


def write_case(case: MachineCase, folder: Path) -> tuple[list[Path], list[Path]]:
    """``case``'s files as CSV in ``folder``: ``calibration/NN.csv`` and ``verify/NN.csv``.

    Each folder is what ``compd fit --data`` and ``compd compare --data`` take
    (several files: one experiment each, in name order).
    """
    written: tuple[list[Path], list[Path]] = ([], [])
    for name, frames, paths in (
        ("calibration", case.calibration, written[0]),
        ("verify", case.verify, written[1]),
    ):
        (folder / name).mkdir(parents=True, exist_ok=True)
        for k, frame in enumerate(frames, 1):
            path = folder / name / f"{k:02d}.csv"
            frame.to_csv(path, index=False, float_format="%.8g")
            paths.append(path)
    return written


def write_log(case: MachineCase, folder: Path) -> Path | None:
    """The case's whole timeline as ``log.csv`` in ``folder`` (None: a case without one).

    What ``compd compare --data log.csv --from CUT`` (:attr:`MachineCase.cut_s`)
    judges: the model run from the log's start through the calibration into the
    verify programme, as the daemon would have run it.
    """
    if case.log is None:
        return None
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "log.csv"
    case.log.to_csv(path, index=False, float_format="%.8g")
    return path
