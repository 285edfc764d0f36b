"""Random sensor layouts for :mod:`compd.sim.machines`: what someone else screwed onto the machine.

A layout of ``n`` sensors (4-24) mixes four kinds, in a shuffled column order
(a user of the file is not told which is which):

- ``part``: a Pt100 on a part that moves the tool (bearings, motor, headstock,
  column front or back, bed, table, enclosure air), reading 5-35 % of the air
  or shop around it, with a lag of 20-300 s; a machine's sensors sit on only
  2-6 of these parts (where someone could reach), so the part that moves the
  tool most may have none and a model has to infer it from the others' history;
- ``duplicate``: a near-duplicate of a ``part`` sensor a few cm away: the same
  lag within 30 %, 3-8 % of a neighbouring part, its own offset and noise;
- ``ambient``: the shop floor only (a guard, a cabinet wall, a pillar), lagging
  5-50 min;
- ``unrelated``: a hydraulic unit or an electrical cabinet with its own slow
  cycle (periods of 0.5-6 h), which no displacement follows.

Now and then one ``part`` sensor has a loose contact (spikes of 0.5-3 degC) or
five times the noise. Readings carry a Pt100 offset within 0.3 degC, white
noise and 0.01 degC quantisation (:func:`read_sensors`).
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

import numpy as np

from compd.sim.realistic import SensorSpec
from compd.sim.sensors import lag

#: Parts a sensor may sit on, and the parts next to each (a near-duplicate reads a little of one).
NEIGHBOURS: dict[str, tuple[str, ...]] = {
    "bearings": ("headstock",),
    "motor": ("headstock",),
    "headstock": ("column_front", "motor", "bearings"),
    "column_front": ("headstock", "column_back"),
    "column_back": ("column_front", "bed"),
    "bed": ("column_back", "table"),
    "table": ("bed",),
    "air": ("ambient",),
}
#: Parts weighed by how often a sensor is put there (the spindle and column most).
_PART_WEIGHTS = {
    "bearings": 3,
    "motor": 2,
    "headstock": 3,
    "column_front": 2,
    "column_back": 2,
    "bed": 1,
    "table": 1,
    "air": 1,
}
KINDS = ("part", "duplicate", "ambient", "unrelated")
OFFSET_DEGC = 0.3
QUANTUM_DEGC = 0.01


@dataclass(frozen=True)
class SensorPlan:
    """Sensor specs in column order, the kind of each, and the unrelated ones' own cycles."""

    specs: tuple[SensorSpec, ...]
    kinds: tuple[str, ...]
    #: Per ``unrelated`` sensor (by column index): (amplitude degC, period s, phase) triples and a level.
    cycles: dict[int, tuple[float, tuple[tuple[float, float, float], ...]]]

    def counts(self) -> dict[str, int]:
        found = Counter(self.kinds)
        return {kind: found.get(kind, 0) for kind in KINDS}

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(f"T{k}" for k in range(1, len(self.specs) + 1))


def _reachable_parts(rng: np.random.Generator) -> list[str]:
    """The 2-6 parts someone put sensors on (weighted: the spindle and column most)."""
    parts = list(_PART_WEIGHTS)
    weights = np.array([_PART_WEIGHTS[p] for p in parts], dtype=float)
    size = int(rng.integers(2, 7))
    return [str(p) for p in rng.choice(parts, size=size, replace=False, p=weights / weights.sum())]


def _part_spec(rng: np.random.Generator, parts: list[str]) -> SensorSpec:
    part = str(rng.choice(parts))
    if part == "air":
        return SensorSpec({"air": 1.0}, rng.uniform(60.0, 300.0), rng.uniform(0.005, 0.03))
    around = rng.uniform(0.05, 0.35)
    surround = "air" if part in ("bearings", "headstock", "column_front", "table") else "ambient"
    return SensorSpec(
        {part: 1.0 - around, surround: around}, rng.uniform(20.0, 300.0), rng.uniform(0.005, 0.03)
    )


def _duplicate(rng: np.random.Generator, of: SensorSpec) -> SensorSpec:
    main = max(of.sites, key=lambda site: of.sites[site])
    neighbour = str(rng.choice(NEIGHBOURS.get(main, ("ambient",))))
    share = rng.uniform(0.03, 0.08)
    sites = {site: weight * (1.0 - share) for site, weight in of.sites.items()}
    sites[neighbour] = sites.get(neighbour, 0.0) + share
    return SensorSpec(sites, of.lag_s * rng.uniform(0.7, 1.3), rng.uniform(0.005, 0.03))


def draw_sensors(rng: np.random.Generator, n: int) -> SensorPlan:
    """A layout of ``n`` sensors (at least two on parts), kinds as in the module docstring."""
    n_ambient = int(rng.integers(0, min(3, n - 2) + 1))
    n_unrelated = int(rng.integers(0, min(2, n - 2 - n_ambient) + 1)) if rng.random() < 0.6 else 0
    rest = n - n_ambient - n_unrelated
    n_duplicate = int(rng.integers(0, rest // 2 + 1)) if rest > 2 else 0
    n_part = rest - n_duplicate
    parts = _reachable_parts(rng)
    specs: list[SensorSpec] = [_part_spec(rng, parts) for _ in range(n_part)]
    kinds = ["part"] * n_part
    faulty = int(rng.integers(n_part)) if rng.random() < 0.25 else None
    if faulty is not None:
        spec = specs[faulty]
        loose = bool(rng.random() < 0.5)
        specs[faulty] = SensorSpec(spec.sites, spec.lag_s, 5 * spec.noise_degc, spikes=loose)
    specs += [_duplicate(rng, specs[int(rng.integers(n_part))]) for _ in range(n_duplicate)]
    kinds += ["duplicate"] * n_duplicate
    specs += [SensorSpec({"ambient": 1.0}, rng.uniform(300.0, 3000.0)) for _ in range(n_ambient)]
    kinds += ["ambient"] * n_ambient
    specs += [SensorSpec({}, rng.uniform(60.0, 600.0)) for _ in range(n_unrelated)]
    kinds += ["unrelated"] * n_unrelated
    order = rng.permutation(n)
    specs = [specs[i] for i in order]
    kinds = [kinds[i] for i in order]
    cycles = {
        k: (
            rng.uniform(22.0, 40.0),
            tuple(
                (rng.uniform(0.2, 1.5), rng.uniform(0.5, 6.0) * 3600.0, rng.uniform(0, 2 * np.pi))
                for _ in range(int(rng.integers(1, 4)))
            ),
        )
        for k, kind in enumerate(kinds)
        if kind == "unrelated"
    }
    return SensorPlan(tuple(specs), tuple(kinds), cycles)


def _spikes_degc(rng: np.random.Generator, time_s: np.ndarray) -> np.ndarray:
    """A loose contact: about one spike an hour of +0.5..3 degC, decaying within a few minutes."""
    out = np.zeros_like(time_s)
    event_s = rng.uniform(0.0, 3600.0)
    while event_s < time_s[-1]:
        after = time_s >= event_s
        out[after] += rng.uniform(0.5, 3.0) * np.exp(-(time_s[after] - event_s) / 90.0)
        event_s += rng.exponential(3600.0)
    return out


def read_sensors(
    plan: SensorPlan, sites: dict[str, np.ndarray], time_s: np.ndarray, seed: int
) -> dict[str, np.ndarray]:
    """Each sensor's logged reading (degC) over ``time_s`` from the true ``sites`` temperatures."""
    step_s = float(time_s[1] - time_s[0])
    out = {}
    for k, (name, spec) in enumerate(zip(plan.names, plan.specs, strict=True)):
        rng = np.random.default_rng([seed, 20, 6, k])
        if k in plan.cycles:
            level, sines = plan.cycles[k]
            true = level + sum(a * np.sin(2 * np.pi * time_s / p + f) for a, p, f in sines)
        else:
            true = sum(weight * sites[site] for site, weight in spec.sites.items())
        reading = lag(np.asarray(true, dtype=float), spec.lag_s, step_s)
        reading = reading + rng.uniform(-OFFSET_DEGC, OFFSET_DEGC)
        reading = reading + rng.normal(0.0, spec.noise_degc, time_s.size)
        if spec.spikes:
            reading = reading + _spikes_degc(rng, time_s)
        out[name] = np.round(reading / QUANTUM_DEGC) * QUANTUM_DEGC
    return out
