"""Known thermal systems to identify: inputs, true TFs and their outputs, simulated with scipy.

Every case is small (10 s sampling, tens of hours) so identification tests
stay cheap, with time constants of 20 min to 2 h as on a machine tool.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.signal


@dataclass(frozen=True, eq=False)
class Case:
    """``y = sum_i lfilter(b_i, a_i, u_i)`` (+ noise in ``y``): the truth an identification should find."""

    sample_time_s: float
    inputs: np.ndarray  # (N, n_inputs), changes from start
    b: tuple[np.ndarray, ...]  # delay folded in as leading zeros
    a: tuple[np.ndarray, ...]
    y_true: np.ndarray
    y: np.ndarray

    def named(self) -> dict[str, np.ndarray]:
        return {f"u{i}_degC": self.inputs[:, i] for i in range(self.inputs.shape[1])}


def held_levels(
    rng: np.random.Generator, n: int, sample_time_s: float, lag_s: float = 600.0
) -> np.ndarray:
    """Random levels held 30 min to 4 h, through a sensor lag, as a change from start."""
    level = np.zeros(n)
    t = 0
    while t < n:
        hold = int(rng.integers(1800, 4 * 3600) / sample_time_s)
        level[t : t + hold] = rng.uniform(-5.0, 5.0)
        t += hold
    pole = np.exp(-sample_time_s / lag_s)
    return scipy.signal.lfilter([1.0 - pole], [1.0, -pole], level - level[0])


def thermal_second_order(
    tau_s: tuple[float, float], gain: float, share: float, sample_time_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """ZOH equivalent (nk = 1) of ``gain * (share / (1 + tau1 s) + (1 - share) / (1 + tau2 s))``."""
    p = np.exp(-sample_time_s / np.asarray(tau_s))
    num = gain * (
        share * (1 - p[0]) * np.array([1.0, -p[1]])
        + (1 - share) * (1 - p[1]) * np.array([1.0, -p[0]])
    )
    return np.concatenate([[0.0], num]), np.poly(p)


def make_case(
    tfs: list[tuple[np.ndarray, np.ndarray]],
    *,
    hours: float,
    sample_time_s: float = 10.0,
    noise_fraction: float = 0.0,
    seed: int = 0,
) -> Case:
    rng = np.random.default_rng(seed)
    n = int(hours * 3600 / sample_time_s)
    inputs = np.column_stack([held_levels(rng, n, sample_time_s) for _ in tfs])
    y_true = np.zeros(n)
    for i, (b, a) in enumerate(tfs):
        y_true += scipy.signal.lfilter(b, a, inputs[:, i])
    noise = noise_fraction * np.std(y_true) * rng.standard_normal(n)
    return Case(
        sample_time_s,
        inputs,
        tuple(b for b, _ in tfs),
        tuple(a for _, a in tfs),
        y_true,
        y_true + noise,
    )
