"""An air-conditioned hall's ambient sensor: the noisy input Swiss-lathe paper denoises.

In a hall whose AC switches on and off, the air at the ambient sensor cycles
by a few tenths of a degree every 10-20 min. The machine's structure, whose
thermal time constants are hours, filters such a cycle to a negligible
displacement (a first-order lag of 2 h passes ``1 / sqrt(1 + (2 pi 7200 /
900)^2)``, about 2 %, of a 15 min cycle), so the twin's physics is left as it
is and only the logged ``T_ambient_degC`` gets the cycle and extra sensor
noise: to a model the cycle is an input disturbance with no output effect,
which is what input denoising is for.

The cycle is a triangle wave (the AC's on/off ramps)::

    c(t) = A (4 |frac(t / P + phi) - 1/2| - 1),   A in degC, P in s

with a random phase ``phi`` and white noise of ``noise_degC`` std on top.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd


@dataclass(frozen=True)
class AirConditioning:
    """The AC cycle seen by the ambient sensor: period in s, half peak-to-peak and noise std in degC."""

    period_s: float = 900.0
    amplitude_degC: float = 0.4
    noise_degC: float = 0.05

    def ambient_disturbance_degC(self, time_s: np.ndarray, seed: int) -> np.ndarray:
        """``c(t)`` plus white noise, at the instants ``time_s``; the same seed gives the same values."""
        rng = np.random.default_rng([seed, 4])
        phase = (np.asarray(time_s, dtype=float) / self.period_s + rng.uniform()) % 1.0
        cycle = self.amplitude_degC * (4.0 * np.abs(phase - 0.5) - 1.0)
        disturbance: np.ndarray = cycle + self.noise_degC * rng.standard_normal(phase.size)
        return disturbance


def air_conditioned(
    frame: pd.DataFrame, seed: int, ac: AirConditioning | None = None
) -> pd.DataFrame:
    """A copy of a twin run whose ``T_ambient_degC`` sensor also reads the AC cycle and its noise."""
    ac = ac or AirConditioning()
    frame = frame.copy()
    frame["T_ambient_degC"] = frame["T_ambient_degC"] + ac.ambient_disturbance_degC(
        frame["time_s"].to_numpy(), seed
    )
    return frame
