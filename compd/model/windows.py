"""Where a model fails: the residue cut into fixed windows, those above a tolerance, and the conditions then.

A fit % over a whole record hides when the model fails. Horejs 2015's air-cutting
model is good at idle and leaves more than 50 um under rough cutting at
4.5 kW: the windows that fail, with the spindle power, speed, feed, door and
coolant at the time, say which operating condition the model has not seen.

Windows are contiguous, ``window_s`` long, starting at ``time_s[0]``; the
last one may be shorter (it holds what is left of the record). A last window
of zero length (a lone sample at its start, as a record of exactly 16 h at
1 Hz ends: 57,601 samples) spans no time and is not judged: it is neither
listed nor counted (:func:`window_count`). A window fails
when the RMS of the residue (um) in it exceeds ``tolerance_um``::

    rms_w = sqrt( mean_{k in w} residue(k)^2 )  >  tolerance_um

Only numpy: one pass of ``np.add.reduceat`` per quantity.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


@dataclass(frozen=True)
class FailingWindow:
    """One window whose residue RMS exceeds the tolerance, with the operating conditions in it."""

    start_s: float
    end_s: float
    """``start_s + window_s``, or the last sample's time for the shorter last window."""
    rms_um: float
    conditions: Mapping[str, float] = field(default_factory=dict)
    """Mean of each condition signal over the window."""
    outside_calibration: tuple[str, ...] = ()
    """Condition signals whose mean over the window lies outside the calibration ``[min, max]``."""


def failing_windows(
    time_s: Array,
    residue_um: Array,
    *,
    tolerance_um: float,
    window_s: float = 900.0,
    conditions: Mapping[str, Array] = MappingProxyType({}),
    ranges: Mapping[str, tuple[float, float]] = MappingProxyType({}),
) -> list[FailingWindow]:
    """Windows of ``residue_um`` whose RMS exceeds ``tolerance_um``, in time order.

    Parameters
    ----------
    time_s
        Sample times in s, increasing (a uniform grid, as :class:`compd.files.data.DataSet` has).
    residue_um
        Measured minus predicted, um, one value per sample.
    tolerance_um
        RMS limit per window, um (> 0).
    window_s
        Window length in s (> 0).
    conditions
        Condition signal name -> values per sample; each failing window gets
        their means.
    ranges
        Signal name -> ``(min, max)`` seen in the calibration data. A
        condition whose mean over a failing window lies outside its range is
        named in ``outside_calibration`` (the mean, not single samples: a
        constant signal's sensor noise must not put it "outside" a range that
        is itself only noise wide); signals without a range are not judged.
    """
    time_s = np.asarray(time_s, dtype=float)
    residue = np.asarray(residue_um, dtype=float)
    if time_s.shape != residue.shape or time_s.ndim != 1 or len(time_s) == 0:
        raise ValueError("time_s and residue_um must be 1-D arrays of the same, non-zero length")
    if not tolerance_um > 0.0:
        raise ValueError(f"tolerance_um must be > 0, got {tolerance_um}")
    if not window_s > 0.0:
        raise ValueError(f"window_s must be > 0, got {window_s}")
    index = _window_index(time_s, window_s)
    starts = np.flatnonzero(np.diff(index, prepend=-1))  # first sample of each occupied window
    counts = np.diff(np.append(starts, len(time_s)))
    rms = np.sqrt(np.add.reduceat(residue**2, starts) / counts)
    judged = np.ones(len(starts), dtype=bool)
    judged[-1] = _last_has_length(time_s, index, window_s)
    failing = np.flatnonzero((rms > tolerance_um) & judged)
    if len(failing) == 0:
        return []
    names = list(conditions)
    means = {
        n: np.add.reduceat(np.asarray(conditions[n], dtype=float), starts) / counts for n in names
    }
    ranged = [n for n in names if n in ranges]
    windows = []
    for w in failing:
        start = time_s[0] + index[starts[w]] * window_s
        last = w == len(starts) - 1
        end = float(time_s[-1]) if last and time_s[-1] < start + window_s else start + window_s
        outside = tuple(n for n in ranged if not ranges[n][0] <= means[n][w] <= ranges[n][1])
        windows.append(
            FailingWindow(
                start_s=float(start),
                end_s=float(end),
                rms_um=float(rms[w]),
                conditions=MappingProxyType({n: float(means[n][w]) for n in names}),
                outside_calibration=outside,
            )
        )
    return windows


def window_count(time_s: Array, window_s: float) -> int:
    """Windows of ``window_s`` the record ``time_s`` is judged in: the last may be shorter, never empty.

    ``ceil((time_s[-1] - time_s[0]) / window_s)``, computed on the same
    window index as :func:`failing_windows` so the two always agree: a
    16 h record at 1 Hz has 64 windows of 15 min, not 65.
    """
    time_s = np.asarray(time_s, dtype=float)
    if len(time_s) == 0:
        return 0
    index = _window_index(time_s, window_s)
    return int(index[-1]) + int(_last_has_length(time_s, index, window_s))


def _window_index(time_s: Array, window_s: float) -> NDArray[np.int64]:
    """The window each sample falls in, from 0."""
    index: NDArray[np.int64] = np.floor((time_s - time_s[0]) / window_s).astype(np.int64)
    return index


def _last_has_length(time_s: Array, index: NDArray[np.int64], window_s: float) -> bool:
    """Whether the last window spans time (more than a lone sample at its start)."""
    return bool(time_s[-1] > time_s[0] + index[-1] * window_s)
