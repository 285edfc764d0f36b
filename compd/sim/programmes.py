"""Random spindle programmes for :mod:`compd.sim.machines`: what a shop runs while it logs.

A programme is a list of ``(speed_rpm, duration_s)`` steps drawn by a seeded
generator up to a given length. The kinds differ in what they show a model:

============  =================================================================================
kind          what it is
============  =================================================================================
cycles        ISO 230-3 style: heat at a constant speed for 1-4 h, cool standing for 1-4 h
ladder        a speed ladder: 0.5-1.5 h steps at rising (or falling) speeds, then standing
constant      one speed for about half the run, then standing (a warm-up run)
production    a new speed every 2-20 min, short stops for tool changes (no long rest)
duty          on/off duty cycle at one speed: 10-60 min periods, 30-80 % on
============  =================================================================================

A calibration and its verify data use different kinds, so a model is judged
on a programme it was not fitted on (issue 20 item 4).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

Steps = list[tuple[float, float]]
_MIN = 60.0
_H = 3600.0


def _speed(rng: np.random.Generator, max_rpm: float, low: float = 0.15) -> float:
    """A speed between ``low`` and all of ``max_rpm``, rounded to 250 rpm."""
    return float(max(250.0, round(rng.uniform(low, 1.0) * max_rpm / 250.0) * 250.0))


def _cycles(rng: np.random.Generator, total_s: float, max_rpm: float) -> Steps:
    steps: Steps = []
    heat_s = rng.uniform(1.0, 4.0) * _H
    cool_s = rng.uniform(1.0, 4.0) * _H
    while sum(d for _, d in steps) < total_s:
        steps += [(_speed(rng, max_rpm, 0.25), heat_s * rng.uniform(0.8, 1.2)), (0.0, cool_s)]
    return steps


def _ladder(rng: np.random.Generator, total_s: float, max_rpm: float) -> Steps:
    steps: Steps = []
    step_s = rng.uniform(0.5, 1.5) * _H
    while sum(d for _, d in steps) < total_s:
        levels = np.linspace(rng.uniform(0.1, 0.3), 1.0, int(rng.integers(4, 7))) * max_rpm
        if rng.random() < 0.3:
            levels = levels[::-1]
        steps += [(float(round(r / 250.0) * 250.0), step_s) for r in levels]
        steps.append((0.0, rng.uniform(1.0, 4.0) * _H))
    return steps


def _constant(rng: np.random.Generator, total_s: float, max_rpm: float) -> Steps:
    on_s = rng.uniform(0.4, 0.7) * total_s
    return [(_speed(rng, max_rpm, 0.4), on_s), (0.0, total_s - on_s + _H)]


def _production(rng: np.random.Generator, total_s: float, max_rpm: float) -> Steps:
    steps: Steps = []
    while sum(d for _, d in steps) < total_s:
        if rng.random() < 0.15:
            steps.append((0.0, rng.uniform(1.0, 5.0) * _MIN))
        else:
            steps.append((_speed(rng, max_rpm), rng.uniform(2.0, 20.0) * _MIN))
    return steps


def _duty(rng: np.random.Generator, total_s: float, max_rpm: float) -> Steps:
    steps: Steps = []
    rpm, period_s, duty = (
        _speed(rng, max_rpm, 0.4),
        rng.uniform(10, 60) * _MIN,
        rng.uniform(0.3, 0.8),
    )
    while sum(d for _, d in steps) < total_s:
        steps += [(rpm, duty * period_s), (0.0, (1.0 - duty) * period_s)]
    return steps


#: Programme kind -> its generator ``f(rng, total_s, max_rpm)``.
PROGRAMMES: dict[str, Callable[[np.random.Generator, float, float], Steps]] = {
    "cycles": _cycles,
    "ladder": _ladder,
    "constant": _constant,
    "production": _production,
    "duty": _duty,
}


def draw_programme(kind: str, rng: np.random.Generator, total_s: float, max_rpm: float) -> Steps:
    """A programme of ``kind`` covering at least ``total_s`` (its last step may run past it)."""
    return PROGRAMMES[kind](rng, total_s, max_rpm)


def speed_on_grid(steps: Steps, time_s: np.ndarray, start_s: float = 0.0) -> np.ndarray:
    """Speed (rpm) of ``steps`` begun at ``start_s`` at ``time_s``; 0 before the start and after the end."""
    edges_s = start_s + np.cumsum([0.0, *(d for _, d in steps)])
    speeds = np.array([0.0, *(r for r, _ in steps), 0.0])
    return np.asarray(speeds[np.searchsorted(edges_s, time_s, side="right")])
