"""Regenerate ``example_spectrum.csv``, the bundled example data (deterministic).

A SPECTRUM-style test after seed 000: one idle hour, the spindle speed
stepped every hour through four levels, then three hours of cooling, with a
shop floor that drifts with the air conditioning. The displacements come from the
bundled models with perturbed parameters (the "real machine" never equals its
model) plus sensor noise, so the examples' fit is realistic, not perfect.

Run: ``python config/make_example_data.py`` (writes next to this file).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import scipy.signal

from compd.files.modelfile import load_model
from compd.model import compile_model, simulate

HERE = Path(__file__).parent
SAMPLE_TIME_S = 10.0
DURATION_S = 8 * 3600


def first_order(u: np.ndarray, gain: float, tau_s: float, dt_s: float = 1.0) -> np.ndarray:
    pole = np.exp(-dt_s / tau_s)
    return scipy.signal.lfilter([0.0, gain * (1 - pole)], [1.0, -pole], u)


def with_gains(path: Path, gains: dict[str, float]):
    model = load_model(path).model
    outputs = tuple(
        replace(
            o,
            submodels=tuple(replace(s, gain=s.gain * gains.get(s.name, 1.0)) for s in o.submodels),
        )
        for o in model.outputs
    )
    return compile_model(replace(model, outputs=outputs))


def main() -> None:
    rng = np.random.default_rng(230_3)
    t = np.arange(0, DURATION_S, 1.0)
    levels_rpm = [0, 3200, 6400, 4800, 1600, 0, 0, 0]
    speed = np.array([levels_rpm[int(s // 3600)] for s in t], dtype=float)
    power_kw = 0.0008 * speed + 0.4 * (speed > 0)
    shop = 20.0 + 0.6 * np.sin(2 * np.pi * t / (5.5 * 3600)) + 0.15 * t / DURATION_S
    spindle = shop + first_order(speed, 2.1e-3, 1500.0)
    ram = shop + first_order(speed, 0.8e-3, 3000.0)
    base = shop[0] + first_order(shop - shop[0], 1.0, 3600.0) + first_order(speed, 0.25e-3, 7200.0)

    z_true = with_gains(HERE / "seed000_hmc_tf.yaml", {"z_heat": 1.07, "etve": 0.85})
    y_true = with_gains(
        HERE / "example_gated_arx.yaml", {"cooling": 1.12, "heating_difference": 0.9}
    )
    signals = {"T_spindle_degC": spindle, "T_shopfloor_degC": shop, "spindle_speed_rpm": speed}

    def run(compiled):
        x = np.column_stack([signals[name] for name in compiled.signals])
        return simulate(compiled, x, compiled.steady_state(x[0])).outputs[:, 0]

    columns = {
        "time_s": t,
        "spindle_speed_rpm": speed,
        "spindle_power_kw": power_kw,
        "T_spindle_degC": spindle + rng.normal(0, 0.03, t.size),
        "T_ram_degC": ram + rng.normal(0, 0.03, t.size),
        "T_base_degC": base + rng.normal(0, 0.03, t.size),
        "T_shopfloor_degC": shop + rng.normal(0, 0.03, t.size),
        "disp_y_um": run(y_true) + rng.normal(0, 0.3, t.size),
        "disp_z_um": run(z_true) + rng.normal(0, 0.5, t.size),
    }
    every = int(SAMPLE_TIME_S)
    frame = pd.DataFrame({k: v[::every] for k, v in columns.items()})
    frame.to_csv(HERE / "example_spectrum.csv", index=False, float_format="%.3f")
    print(f"wrote {len(frame)} rows to {HERE / 'example_spectrum.csv'}")


if __name__ == "__main__":
    main()
