"""What the machine's logger would record: sensor lag, noise and calibration offsets.

Temperatures are read by Pt100 class A sensors (IEC 60751): each reading is
the true temperature of its node passed through a first-order lag (the
sensor's thermal contact, ``τ`` of 20–60 s), plus a fixed offset within the
class-A tolerance ``±(0.15 + 0.002 |T|) degC`` and white noise of 0.015 degC
std. Displacements (capacitive probes against a test mandrel, ISO 230-3)
carry 0.3 um std of white noise. Controller signals are logged as the
controller reports them: speed and feed exactly, spindle power with 10 W of
noise while the spindle turns.

The lag per sample is exact for an input held over the sample::

    y[k] = a y[k−1] + (1 − a) x[k],   a = exp(−Ts / τ)
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

from compd.sim.machine import MachineParameters, noload_power_kw
from compd.sim.thermal import MachineInputs, TwinState

#: Column order of a twin data file (names are a contract with the rest of compd).
COLUMNS = (
    "time_s",
    "spindle_speed_rpm",
    "spindle_power_kw",
    "feed_x_mm_per_min",
    "feed_z_mm_per_min",
    "door_open",
    "T_coolant_degC",
    "T_ambient_degC",
    "T_spindle_degC",
    "T_motor_degC",
    "T_headstock_degC",
    "T_column_front_degC",
    "T_column_back_degC",
    "T_bed_degC",
    "disp_x_um",
    "disp_y_um",
    "disp_z_um",
)

#: Logged temperature column -> the node (or boundary) its sensor sits on.
TEMPERATURE_SENSORS: dict[str, str] = {
    "T_coolant_degC": "coolant",
    "T_ambient_degC": "ambient",
    "T_spindle_degC": "bearings",
    "T_motor_degC": "motor",
    "T_headstock_degC": "headstock",
    "T_column_front_degC": "column_front",
    "T_column_back_degC": "column_back",
    "T_bed_degC": "bed",
}
DISPLACEMENT_COLUMNS = ("disp_x_um", "disp_y_um", "disp_z_um")

PT100_NOISE_DEGC = 0.015
DISPLACEMENT_NOISE_UM = 0.3
POWER_NOISE_KW = 0.01
LAG_RANGE_S = (20.0, 60.0)


def class_a_tolerance_degc(temperature_degc: float) -> float:
    """Pt100 class A tolerance ``0.15 + 0.002 |T|`` in degC (IEC 60751)."""
    return 0.15 + 0.002 * abs(temperature_degc)


@dataclass(frozen=True)
class SensorSet:
    """The drawn properties of one machine's sensors: per-sensor lag (s) and offset (degC)."""

    lag_s: dict[str, float]
    offset_degc: dict[str, float]

    @classmethod
    def draw(
        cls,
        rng: np.random.Generator,
        nominal_degc: float = 20.0,
        sites: Mapping[str, str] = TEMPERATURE_SENSORS,
    ) -> SensorSet:
        """Lags uniform in :data:`LAG_RANGE_S`, offsets uniform within the class-A tolerance.

        ``sites``: the sensors drawn (column -> node), by default the logged ones.
        """
        tol = class_a_tolerance_degc(nominal_degc)
        names = list(sites)
        lags = rng.uniform(*LAG_RANGE_S, size=len(names))
        offsets = rng.uniform(-tol, tol, size=len(names))
        return cls(
            dict(zip(names, lags.tolist(), strict=True)),
            dict(zip(names, offsets.tolist(), strict=True)),
        )


def lag(values: np.ndarray, lag_s: float, sample_time_s: float) -> np.ndarray:
    """First-order lag of ``values`` starting in equilibrium with ``values[0]``."""
    a = float(np.exp(-sample_time_s / lag_s))
    x = np.asarray(values, dtype=float)
    out, _ = lfilter([1.0 - a], [1.0, -a], x, zi=[a * x[0]])
    return np.asarray(out)


def read_temperatures(
    true_degc: dict[str, np.ndarray],
    sensors: SensorSet,
    sample_time_s: float,
    rng: np.random.Generator,
) -> dict[str, np.ndarray]:
    """Logged temperature columns from true sensor-site temperatures (keys of :data:`TEMPERATURE_SENSORS`)."""
    out = {}
    for name in TEMPERATURE_SENSORS:
        x = true_degc[name]
        noise = rng.normal(0.0, PT100_NOISE_DEGC, size=x.shape)
        out[name] = lag(x, sensors.lag_s[name], sample_time_s) + sensors.offset_degc[name] + noise
    return out


def read_displacements(true_um: np.ndarray, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Logged ``disp_*_um`` columns from the true displacement ``(3, samples)``."""
    noisy = true_um + rng.normal(0.0, DISPLACEMENT_NOISE_UM, size=true_um.shape)
    return dict(zip(DISPLACEMENT_COLUMNS, noisy, strict=True))


def reported_power_kw(
    params: MachineParameters,
    speed_rpm: np.ndarray,
    cutting_power_kw: np.ndarray,
    rng: np.random.Generator,
) -> np.ndarray:
    """Spindle power as the drive reports it: no-load + cutting power, noisy while turning, kW."""
    speed = np.asarray(speed_rpm, dtype=float)
    power = noload_power_kw(params, speed) + np.asarray(cutting_power_kw, dtype=float)
    noise = rng.normal(0.0, POWER_NOISE_KW, size=speed.shape)
    return np.where(speed != 0, np.maximum(power + noise, 0.0), 0.0)


class LivePt100s:
    """Pt100s on the twin's ``sites`` (column -> node or boundary) read one sample at a time:
    each the true temperature through its lag, plus its offset and white noise from ``rng``.

    The first :meth:`read` starts every lag in equilibrium with the temperature it reads.
    """

    def __init__(
        self,
        sensors: SensorSet,
        sites: Mapping[str, str],
        sample_time_s: float,
        rng: np.random.Generator,
    ) -> None:
        self.sensors = sensors
        self.sites = dict(sites)
        self.rng = rng
        self._a = {name: float(np.exp(-sample_time_s / t)) for name, t in sensors.lag_s.items()}
        self._lagged: dict[str, float] | None = None

    def read(self, state: TwinState, u: MachineInputs) -> dict[str, float]:
        """Each sensor's reading (degC) at the twin's ``state`` under inputs ``u``."""
        true = {
            name: u.T_coolant_degC
            if site == "coolant"
            else u.T_ambient_degC
            if site == "ambient"
            else state.temperature(site)
            for name, site in self.sites.items()
        }
        if self._lagged is None:
            self._lagged = dict(true)
        else:
            for name, x in true.items():
                a = self._a[name]
                self._lagged[name] = a * self._lagged[name] + (1.0 - a) * x
        noise = self.rng.normal(0.0, PT100_NOISE_DEGC, size=len(true))
        return {
            name: self._lagged[name] + self.sensors.offset_degc[name] + float(e)
            for name, e in zip(true, noise, strict=True)
        }


class SensorBank:
    """The same sensors read live, one sample at a time, for closed-loop use with :class:`MachineTwin`.

    :meth:`read` returns one logged row (every :data:`COLUMNS` name but
    ``time_s``); the first call starts every lag in equilibrium with the
    temperature it reads, as a record starts.
    """

    def __init__(
        self,
        sensors: SensorSet,
        sample_time_s: float,
        rng: np.random.Generator,
        params: MachineParameters | None = None,
    ) -> None:
        self.sensors = sensors
        self.params = params or MachineParameters()
        self.rng = rng
        self._temperatures = LivePt100s(sensors, TEMPERATURE_SENSORS, sample_time_s, rng)

    def read(self, state: TwinState, u: MachineInputs) -> dict[str, float]:
        temps = self._temperatures.read(state, u)
        disp = state.displacement_um + self.rng.normal(0.0, DISPLACEMENT_NOISE_UM, size=3)
        power = reported_power_kw(
            self.params, np.array([u.spindle_speed_rpm]), np.array([u.cutting_power_kw]), self.rng
        )
        row = {
            "spindle_speed_rpm": u.spindle_speed_rpm,
            "spindle_power_kw": float(power[0]),
            "feed_x_mm_per_min": abs(u.feed_x_mm_per_min),
            "feed_z_mm_per_min": abs(u.feed_z_mm_per_min),
            "door_open": float(u.door_open),
            **temps,
            **dict(zip(DISPLACEMENT_COLUMNS, disp.tolist(), strict=True)),
        }
        return {name: row[name] for name in COLUMNS[1:]}
