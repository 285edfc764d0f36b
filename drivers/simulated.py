"""The simulated machine: replays a logged data file as live signals and keeps what is written.

It lets ``compd run`` work without a machine (demos, CI, tests) through the
very same loop as a real bus. At clock time ``t`` (seconds since
:meth:`SimulatedDriver.open`) a read returns every requested column of the
data file linearly interpolated at data time::

    t_data = start_s + time_scale * t        (wrapped modulo the file's length when ``loop``)

Writes are kept in :attr:`SimulatedDriver.written` (last value per address)
and counted. For tests and demos it injects faults, from its settings or by
calling :meth:`SimulatedDriver.inject`: a signal stuck at its current value,
NaN, a fixed (e.g. out-of-range) value, or the whole connection dropping.
"""

from __future__ import annotations

import bisect
from array import array
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from compd.errors import DriverDisconnectedError, DriverProtocolError
from compd.files.plaincsv import read_plain_csv
from compd.files.yamlplace import resolve_path

FaultKind = Literal["stuck", "nan", "value", "drop"]


class FaultSettings(BaseModel):
    """A fault scheduled at ``start_s`` (clock seconds after open) for ``duration_s``."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    kind: FaultKind
    address: str | None = None
    start_s: float = Field(ge=0)
    duration_s: float = Field(gt=0)
    value: float | None = None


class SimulatedSettings(BaseModel):
    """``drivers.<name>.settings`` of a ``type: simulated`` driver."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    data: str = Field(min_length=1, description="data file: path or bundled:NAME")
    time_scale: float = Field(default=1.0, gt=0, description="data seconds per clock second")
    start_s: float = Field(default=0.0, ge=0, description="where in the file to start, s")
    loop: bool = True
    faults: tuple[FaultSettings, ...] = ()


@dataclass
class _Fault:
    kind: FaultKind
    address: str | None
    start_s: float
    end_s: float
    value: float | None

    def active(self, t_s: float) -> bool:
        return self.start_s <= t_s < self.end_s


def _record(path: Path) -> tuple[np.ndarray, Mapping[str, np.ndarray]]:
    """The record's times and columns: a plain CSV with numpy alone, any other through load_data.

    ``load_data`` (pandas, ~40 MB) is imported only for a record that is not
    plain (:mod:`compd.files.plaincsv`), so the daemon replaying the bundled
    example maps no pandas.
    """
    plain = read_plain_csv(path)
    if plain is not None:
        return plain
    from compd.files.data import load_data

    data = load_data(path)
    return data.time_s, data.columns


def _doubles(values: object) -> array[float]:
    """``values`` as packed doubles: indexed, a Python float as from a list, but 8 bytes a
    sample, not 32 (a float object and the list's slot): 0.55 MB less for the bundled record."""
    packed = array("d")
    packed.frombytes(np.ascontiguousarray(values, dtype=np.float64).tobytes())
    return packed


class SimulatedDriver:
    """Replays ``settings.data`` on the service's clock; see the module docstring."""

    settings_model = SimulatedSettings

    def __init__(
        self, settings: SimulatedSettings, *, now: Callable[[], float], base_dir: Path
    ) -> None:
        self.settings = settings
        self._now = now
        time_s, columns = _record(resolve_path(settings.data, base_dir))
        # Indexed as Python floats: one read interpolates a handful of scalars, where
        # numpy's per-call overhead would cost more than the arithmetic.
        self._time_s = _doubles(time_s)
        self._columns = {name: _doubles(v) for name, v in columns.items()}
        self._t0: float | None = None
        self._faults = [
            _Fault(f.kind, f.address, f.start_s, f.start_s + f.duration_s, f.value)
            for f in settings.faults
        ]
        self._stuck: dict[str, float] = {}
        #: The sample interval of the last read (:meth:`_locate`).
        self._last_i = 0
        #: Last value written per address.
        self.written: dict[str, float] = {}
        #: Number of successful ``write`` calls.
        self.writes = 0
        #: Number of successful ``open`` calls.
        self.opens = 0

    @staticmethod
    def reads_back(settings: SimulatedSettings) -> bool:
        """No: what it keeps of the writes lives and dies with this driver, not with a machine."""
        return False

    @property
    def columns(self) -> tuple[str, ...]:
        return tuple(self._columns)

    def elapsed_s(self) -> float:
        """Clock seconds since the first open (0 before it)."""
        return 0.0 if self._t0 is None else self._now() - self._t0

    def inject(
        self,
        kind: FaultKind,
        address: str | None = None,
        *,
        duration_s: float,
        value: float | None = None,
    ) -> None:
        """Start a fault now: ``stuck``/``nan``/``value`` on ``address``, or ``drop`` the connection."""
        if kind != "drop" and address is None:
            raise ValueError(f"a {kind!r} fault needs an address")
        start = self.elapsed_s()
        self._faults.append(_Fault(kind, address, start, start + duration_s, value))

    async def open(self) -> None:
        if self._t0 is None:
            self._t0 = self._now()
        self._check_connected()
        self.opens += 1

    async def read(self, points: Sequence[str]) -> dict[str, float]:
        t_s = self.elapsed_s()
        if self._faults:  # a dropped connection, where faults were set (read every tick: cheap)
            self._check_connected(t_s)
        columns = self._columns
        if not all(map(columns.__contains__, points)):
            unknown = [p for p in points if p not in columns]
            raise DriverProtocolError(
                f"simulated data {self.settings.data} has no column(s) {unknown}; "
                f"it has {sorted(columns)}"
            )
        i, frac = self._locate(self._data_time(t_s))
        values = {}
        for p in points:
            column = columns[p]
            values[p] = column[i] + frac * (column[i + 1] - column[i]) if frac else column[i]
        for fault in self._faults:
            if fault.address in values and fault.active(t_s):
                if fault.kind == "stuck":
                    values[fault.address] = self._stuck.setdefault(
                        fault.address, values[fault.address]
                    )
                elif fault.kind == "nan":
                    values[fault.address] = float("nan")
                elif fault.kind == "value" and fault.value is not None:
                    values[fault.address] = fault.value
        for address in list(self._stuck):
            if not any(
                f.kind == "stuck" and f.address == address and f.active(t_s) for f in self._faults
            ):
                del self._stuck[address]
        return values

    async def write(self, values: Mapping[str, float]) -> None:
        if self._faults:
            self._check_connected()
        self.written.update(values)
        self.writes += 1

    async def close(self) -> None:
        return None

    def _locate(self, data_t: float) -> tuple[int, float]:
        """Sample index ``i`` and fraction of the way to ``i + 1`` for data time ``data_t``."""
        times = self._time_s
        i = self._last_i
        # Read after read, the data time moves on by a tick: the same sample interval as the
        # last read's, or the next. Either found, it is bisect's answer (the times increase);
        # else bisect: a search touches a dozen places in a long record, each after a sleep.
        if not 0 <= i < len(times) - 1 or not times[i] <= data_t < times[i + 1]:
            i += 1
            if not 0 <= i < len(times) - 1 or not times[i] <= data_t < times[i + 1]:
                i = bisect.bisect_right(times, data_t) - 1
        self._last_i = i
        if i < 0:
            return 0, 0.0
        if i >= len(times) - 1:
            return len(times) - 1, 0.0
        return i, (data_t - times[i]) / (times[i + 1] - times[i])

    def _data_time(self, t_s: float) -> float:
        data_t = self.settings.start_s + self.settings.time_scale * t_s
        times = self._time_s
        span = times[-1]
        if self.settings.loop and len(times) > 1:
            # One sample period past the end wraps to the start, so the wrap
            # interpolates nothing across the seam.
            data_t %= span + (times[1] - times[0])
        return min(data_t, span)

    def _check_connected(self, t_s: float | None = None) -> None:
        """Raise as a dropped connection would while a ``drop`` fault is active (at ``t_s``: now)."""
        if t_s is None:
            t_s = self.elapsed_s()
        if any(f.kind == "drop" and f.active(t_s) for f in self._faults):
            raise DriverDisconnectedError("simulated connection dropped")
