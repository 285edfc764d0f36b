"""The model and the data every benchmark runs on, built once here so the scripts measure the same thing.

The model is the size the project's targets are stated for: 10 sub-models of
4th order (nk = 1) over 3 axis outputs and 7 signals. Each sub-model is the
zero-order-hold equivalent at 1 s of a sum of four first-order thermal lags::

    TF(z^-1) = sum_i  w_i (1 - p_i) z^-1 / (1 - p_i z^-1),   p_i = exp(-Ts / tau_i)

with time constants ``tau_i`` from 60 s to 3 h, so the denominator is the
product of four first-order sections and the static gain is ``sum_i w_i``
(um per unit of input). Some sub-models subtract a second signal (``minus``),
some are gated on the spindle (on the output, on the input, and one active
while the spindle stands still), some have a fixed reference: one tick
exercises every branch of ``TickRunner.step``.

The data is a synthetic week at 1 Hz: a daily ambient cycle, two shifts a day
on weekdays with random spindle cycles, and temperatures that follow through
first-order lags, with sensor noise.
"""

from __future__ import annotations

import os
import platform

import numpy as np
import scipy.signal

from compd.model import (
    CompiledModel,
    DiscreteTF,
    Gate,
    GateTarget,
    InputSpec,
    Model,
    Output,
    SubModel,
    compile_model,
)

SAMPLE_TIME_S = 1.0
#: How closely two float64 implementations of this model can agree, in um.
#: Not 1e-9: a 4th-order denominator with poles at exp(-1/10800) = 0.99991
#: amplifies rounding in the delay line, so two correct implementations that
#: merely order their additions differently (numpy's DF2T in ``step``, C's in
#: ``lfilter``, a direct-form loop) drift apart by up to ~0.01 um over a week,
#: on outputs of ~100 um; 0.05 um is still far below any compensation
#: resolution while a wrong coefficient, gate or reference misses it by microns.
AGREE_UM = 0.05
WEEK_SAMPLES = 7 * 86_400
#: A 20,000-sample window starting at 08:00 on Monday: the spindle starts and
#: stops many times in it, so the gates switch while it is measured.
BUSY_START = 8 * 3600


def thermal_tf(time_constants_s: tuple[float, ...], weights_um: tuple[float, ...]) -> DiscreteTF:
    """``sum_i w_i (1 - p_i) z^-1 / (1 - p_i z^-1)`` with ``p_i = exp(-Ts / tau_i)``, as one TF with nk = 1."""
    poles = np.exp(-SAMPLE_TIME_S / np.asarray(time_constants_s))
    den = np.poly(poles)
    num = np.zeros(len(poles))
    for i, (pole, weight) in enumerate(zip(poles, weights_um, strict=True)):
        num += weight * (1.0 - pole) * np.poly(np.delete(poles, i))
    return DiscreteTF.from_coefficients(num, den, nk=1)


_RUNNING = Gate("spindle_speed_rpm", 0.0, True, GateTarget.OUTPUT)
_RUNNING_IN = Gate("spindle_speed_rpm", 0.0, True, GateTarget.INPUT)
_STANDING = Gate("spindle_speed_rpm", 1.0, False, GateTarget.OUTPUT)

#: output, sub-model, signal, minus, reference (None: value at start), gate, gain,
#: then the four time constants (s) and their static gains (um per unit of input).
# fmt: off
_WIRING = (
    ("disp_z_um", "spindle_heat", "T_spindle_degC", "T_ambient_degC", None, _RUNNING, 1.0,
     (60, 600, 2400, 9000), (0.3, 0.8, 1.2, 0.4)),
    ("disp_z_um", "spindle_power", "spindle_power_kw", None, 0.0, _RUNNING_IN, 1.0,
     (90, 900, 3600, 10800), (0.4, 1.1, 0.9, 0.3)),
    ("disp_z_um", "column", "T_column_degC", "T_ambient_degC", None, None, 0.9,
     (300, 1500, 5400, 10800), (1.5, -0.6, 3.0, 2.2)),
    ("disp_z_um", "ambient_z", "T_ambient_degC", None, None, None, 1.0,
     (120, 1200, 4800, 10800), (0.3, 0.7, 1.4, 0.9)),
    ("disp_x_um", "bed", "T_bed_degC", "T_ambient_degC", None, None, 1.0,
     (600, 1800, 7200, 10800), (1.0, 2.0, 1.5, 0.8)),
    ("disp_x_um", "coolant", "T_coolant_degC", "T_bed_degC", None, _RUNNING_IN, 1.0,
     (60, 240, 1200, 3600), (0.5, 0.9, 0.4, 0.2)),
    ("disp_x_um", "ambient_x", "T_ambient_degC", None, 20.0, None, 1.0,
     (180, 900, 3600, 9000), (0.2, -0.4, 1.0, 0.6)),
    ("disp_y_um", "column_y", "T_column_degC", "T_ambient_degC", None, None, 1.0,
     (240, 1200, 4200, 10800), (0.6, 1.2, 0.8, 0.4)),
    ("disp_y_um", "spindle_y", "T_spindle_degC", None, 20.0, _RUNNING, 1.1,
     (60, 480, 1800, 7200), (0.3, 0.8, 0.5, 0.2)),
    ("disp_y_um", "standstill", "T_ambient_degC", None, None, _STANDING, 1.0,
     (90, 600, 3000, 10800), (0.2, 0.3, 0.5, 0.4)),
)
# fmt: on


def build_model() -> Model:
    """3 outputs, 10 sub-models of 4th order, 7 signals: the wiring table above."""
    outputs: dict[str, list[SubModel]] = {}
    for output, name, signal, minus, reference, gate, gain, tau_s, weights_um in _WIRING:
        tf = thermal_tf(tau_s, weights_um)
        sub = SubModel(name, name, InputSpec(signal, minus, reference), tf, gain, gate)
        outputs.setdefault(output, []).append(sub)
    return Model(
        "bench_10x4",
        SAMPLE_TIME_S,
        tuple(Output(name, tuple(subs)) for name, subs in outputs.items()),
    )


def build_compiled() -> CompiledModel:
    compiled = compile_model(build_model())
    assert compiled.n_submodels == 10 and compiled.n_states == 4, "benchmark model changed shape"
    return compiled


def _lag(x: np.ndarray, tau_s: float, start: float) -> np.ndarray:
    """First-order lag of ``x`` with time constant ``tau_s``, starting at ``start``."""
    pole = np.exp(-SAMPLE_TIME_S / tau_s)
    y, _ = scipy.signal.lfilter([1.0 - pole], [1.0, -pole], x, zi=[pole * start])
    return y


def _spindle_speed_rpm(rng: np.random.Generator, n: int) -> np.ndarray:
    """Random on/off cycles (1-30 min on, 1-10 min off) inside 06:00-22:00 on weekdays."""
    speed = np.zeros(n)
    t = 0
    while t < n:
        on_s, off_s = int(rng.integers(60, 1800)), int(rng.integers(60, 600))
        speed[t : t + on_s] = rng.uniform(2000.0, 12000.0)
        t += on_s + off_s
    seconds = np.arange(n)
    hour, day = (seconds % 86_400) / 3600.0, seconds // 86_400
    speed[(hour < 6.0) | (hour >= 22.0) | (day >= 5)] = 0.0
    return speed


def week_signals(
    order: tuple[str, ...], n_samples: int = WEEK_SAMPLES, seed: int = 0
) -> np.ndarray:
    """``(n_samples, len(order))`` signals in ``order`` (``compiled.signals``), as a 1 Hz logger records them."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_samples) * SAMPLE_TIME_S
    ambient = 20.0 + 1.5 * np.sin(2 * np.pi * (t / 86_400 - 0.375))
    speed = _spindle_speed_rpm(rng, n_samples)
    power = speed * 1.5e-3
    spindle = ambient[0] + _lag(power * 2.0, 900.0, 0.0) + _lag(ambient - ambient[0], 1800.0, 0.0)
    bed = _lag(ambient + 0.2 * power, 5400.0, ambient[0])
    column = _lag(0.5 * spindle + 0.5 * ambient, 3600.0, ambient[0])
    coolant = _lag(ambient + 0.5 * power, 300.0, ambient[0])
    temperatures = {
        "T_spindle_degC": spindle,
        "T_bed_degC": bed,
        "T_column_degC": column,
        "T_ambient_degC": ambient,
        "T_coolant_degC": coolant,
    }
    by_name = {name: x + rng.normal(0.0, 0.02, n_samples) for name, x in temperatures.items()}
    by_name |= {"spindle_speed_rpm": speed, "spindle_power_kw": power}
    return np.column_stack([by_name[name] for name in order])


def environment() -> str:
    """One line naming what produced the figures, printed by every script."""
    return (
        f"python {platform.python_version()}, numpy {np.__version__}, scipy {scipy.__version__}, "
        f"{platform.machine()}, {os.cpu_count()} CPUs"
    )


def verdict(passed: bool) -> str:
    return "PASS" if passed else "FAIL"
