"""A machine record with a known missing effect, for the failing-window and diagnosis tests.

12 hours at 10 s. The model (``MODEL_YAML``) knows one effect: the spindle
bearings, ``4 um/K`` of ``T_spindle_degC`` through a 10-min lag. The
"machine" also has the cutting-process effect of Horejs 2015 that the model
lacks: ``1.5 um/kW`` of ``spindle_power_kw`` through a 30-min lag. From 8 h
to 10 h the machine cuts rough at 4.5 kW, beyond the 0..2 kW the model's
calibration data saw, so that is where the model fails. Every other signal
(speed, feed, door, coolant, ambient) is logged but plays no part in the
displacement.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import scipy.signal

SAMPLE_TIME_S = 10.0
HOURS = 12
ROUGH_START_S = 8 * 3600.0
ROUGH_END_S = 10 * 3600.0
POWER_GAIN_UM_PER_KW = 1.5
POWER_TAU_S = 1800.0

MODEL_YAML = """\
schema: compd.model/1
name: spindle-only
sample_time_s: 10.0
outputs:
  disp_z_um:
    submodels:
      - name: spindle
        effect: spindle bearings
        input: {signal: T_spindle_degC, reference: start}
        tf:
          form: continuous
          power_order: ascending
          num: [4.0]
          den: [1.0, 600.0]
provenance:
  calibration:
    data: calibration.csv
    samples: 4320
    sample_time_s: 10.0
    rms_um: {disp_z_um: 0.6}
    ranges:
      spindle_power_kw: [0.0, 2.0]
      spindle_speed_rpm: [0.0, 12000.0]
      T_spindle_degC: [19.0, 40.0]
"""


def lag(x: np.ndarray, tau_s: float) -> np.ndarray:
    """Zero-order-hold first-order lag of ``x - x[0]`` with unit static gain (nk = 1)."""
    pole = np.exp(-SAMPLE_TIME_S / tau_s)
    return scipy.signal.lfilter([0.0, 1.0 - pole], [1.0, -pole], x - x[0])


def zoh_lag(x: np.ndarray, tau_s: float) -> np.ndarray:
    """The model's own ZOH discretisation of ``1 / (1 + tau s)`` (no extra delay), from ``x[0]``."""
    pole = np.exp(-SAMPLE_TIME_S / tau_s)
    return scipy.signal.lfilter([0.0, 1.0 - pole], [1.0, -pole], x - x[0])


def signals(seed: int = 0) -> pd.DataFrame:
    """The logged record, with ``disp_z_um`` = model's effect + the missing power effect + noise."""
    rng = np.random.default_rng(seed)
    n = int(HOURS * 3600 / SAMPLE_TIME_S)
    t = np.arange(n) * SAMPLE_TIME_S
    speed = np.zeros(n)
    k = 0
    while k < n:
        on, off = int(rng.integers(30, 180)), int(rng.integers(10, 60))
        speed[k : k + on] = rng.uniform(3000.0, 10000.0)
        k += on + off
    rough = (t >= ROUGH_START_S) & (t < ROUGH_END_S)
    power = np.where(speed > 0, 0.3 + 1.2e-4 * speed, 0.0)
    power[rough & (speed > 0)] = 4.5
    spindle = 20.0 + lag(1.5e-3 * speed, 900.0)
    ambient = 20.0 + 0.8 * np.sin(2 * np.pi * t / 86_400.0)
    coolant = 20.0 + lag(ambient, 3600.0) + 0.5 * lag(power, 600.0)
    feed = np.where(speed > 0, rng.uniform(500.0, 3000.0, n), 0.0)
    door = (rng.random(n) < 0.01).astype(float)
    disp = (
        4.0 * zoh_lag(spindle, 600.0)
        + POWER_GAIN_UM_PER_KW * lag(power, POWER_TAU_S)
        + rng.normal(0.0, 0.1, n)
    )
    return pd.DataFrame(
        {
            "time_s": t,
            "spindle_speed_rpm": speed,
            "spindle_power_kw": power,
            "feed_x_mm_per_min": feed,
            "door_open": door,
            "T_coolant_degC": coolant + rng.normal(0.0, 0.02, n),
            "T_ambient_degC": ambient + rng.normal(0.0, 0.02, n),
            "T_spindle_degC": spindle,
            "disp_x_um": rng.normal(0.0, 1.0, n),
            "disp_z_um": disp,
        }
    )


def write_case(folder: Path, seed: int = 0) -> tuple[Path, Path]:
    """``(model.yaml, data.csv)`` in ``folder``."""
    model, data = folder / "model.yaml", folder / "data.csv"
    model.write_text(MODEL_YAML)
    signals(seed).to_csv(data, index=False, float_format="%.6f")
    return model, data
