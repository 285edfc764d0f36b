"""Causal low-pass filters that stand in for offline EMD denoising in the running model.

Swiss-lathe paper removes the first intrinsic mode function (IMF) of empirical mode
decomposition from noisy inputs before identification. EMD is not causal:
every sample's envelopes are splines through extrema on both sides of it, so
the 1 Hz service cannot compute it. What the service runs instead is a
low-pass of ``stages`` equal first-order sections, each the exact
discretisation of a sensor-like lag held over the sample::

    y[k] = a y[k-1] + (1 - a) x[k],   a = exp(-Ts / tau_s)

i.e. ``LP(z^-1) = ((1 - a) / (1 - a z^-1)) ** stages`` (unity static gain,
no delay), whose time constant is *matched*: chosen on the calibration data
so that the low-passed raw input is, in least squares (degC RMS), closest to
the EMD-denoised one. The low-pass is then multiplied into the sub-model's
TF (``TF(z^-1) LP(z^-1)``: a polynomial product of numerators and of
denominators), so the model file needs no new concept and the service runs
it unchanged.

Pure numerics: numpy and scipy, no files, no logging.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.signal

from compd.errors import ModelError
from compd.model.transfer import DiscreteTF

#: Default grid of matched time constants: 40 values, log-spaced from 10 s to 2 h.
DEFAULT_TAU_GRID_S: tuple[float, ...] = tuple(float(t) for t in np.geomspace(10.0, 7200.0, 40))


@dataclass(frozen=True)
class LowPass:
    """``stages`` equal first-order lags of time constant ``tau_s`` seconds each (unity static gain)."""

    tau_s: float
    stages: int = 1

    def __post_init__(self) -> None:
        if not (np.isfinite(self.tau_s) and self.tau_s > 0.0):
            raise ModelError(f"a low-pass time constant must be > 0 s, got {self.tau_s}")
        if self.stages not in (1, 2):
            raise ModelError(f"a low-pass has 1 or 2 stages, got {self.stages}")

    def tf(self, sample_time_s: float) -> DiscreteTF:
        """``((1 - a) / (1 - a z^-1)) ** stages`` with ``a = exp(-Ts / tau_s)``."""
        if not sample_time_s > 0.0:
            raise ModelError(f"sample time must be > 0 s, got {sample_time_s}")
        a = float(np.exp(-sample_time_s / self.tau_s))
        num = np.array([1.0])
        den = np.array([1.0])
        for _ in range(self.stages):
            num = np.convolve(num, [1.0 - a])
            den = np.convolve(den, [1.0, -a])
        return DiscreteTF.from_coefficients(num, den, 0)

    def apply(self, x: np.ndarray, sample_time_s: float) -> np.ndarray:
        """The low-passed ``x``, started in equilibrium with ``x[0]`` (as the service starts)."""
        x = np.asarray(x, dtype=float)
        tf = self.tf(sample_time_s)
        filtered: np.ndarray = scipy.signal.lfilter(tf.b, tf.a, x - x[0]) + x[0]
        return filtered


def cascade(tf: DiscreteTF, lowpass: DiscreteTF) -> DiscreteTF:
    """``TF(z^-1) LP(z^-1)``: numerators and denominators multiplied, delays added.

    Filtering an input with ``lowpass`` and then ``tf`` gives the same output
    as the product from rest (both are linear time-invariant), so a sub-model
    whose TF is the product reads the raw input and sees the low-passed one.
    """
    return DiscreteTF.from_coefficients(
        np.convolve(tf.num, lowpass.num), np.convolve(tf.den, lowpass.den), tf.nk + lowpass.nk
    )


@dataclass(frozen=True)
class MatchedLowPass:
    """The low-pass closest to a target (e.g. EMD-denoised) signal, and how close it is.

    ``rms_degC``: RMS of ``LP(raw) - target`` over the record (in the
    input's unit; degC for a temperature); ``raw_rms_degC``: RMS of
    ``raw - target``, the noise the target removed, for scale.
    """

    lowpass: LowPass
    rms_degC: float
    raw_rms_degC: float
    filtered: np.ndarray


def match_lowpass(
    raw: np.ndarray,
    target: np.ndarray,
    sample_time_s: float,
    *,
    taus_s: Sequence[float] = DEFAULT_TAU_GRID_S,
    stages: Sequence[int] = (1, 2),
) -> MatchedLowPass:
    """The ``LowPass`` over the grid ``taus_s`` x ``stages`` minimising ``RMS(LP(raw) - target)``.

    A grid rather than a continuous optimiser: the RMS is flat near its
    minimum and may have several local minima (lag against noise), and 80
    ``lfilter`` runs over a day at 1 s take well under a second.
    """
    raw = np.asarray(raw, dtype=float)
    target = np.asarray(target, dtype=float)
    if raw.shape != target.shape or raw.ndim != 1 or raw.size < 2:
        raise ModelError(
            f"raw and target must be 1-D arrays of equal length >= 2, got {raw.shape} and "
            f"{target.shape}"
        )
    if len(taus_s) == 0:
        raise ModelError("the grid of time constants is empty")
    best: MatchedLowPass | None = None
    for n in stages:
        for tau in taus_s:
            lowpass = LowPass(float(tau), int(n))
            filtered = lowpass.apply(raw, sample_time_s)
            rms = float(np.sqrt(np.mean((filtered - target) ** 2)))
            if best is None or rms < best.rms_degC:
                best = MatchedLowPass(lowpass, rms, 0.0, filtered)
    assert best is not None  # the grid is not empty
    raw_rms = float(np.sqrt(np.mean((raw - target) ** 2)))
    return MatchedLowPass(best.lowpass, best.rms_degC, raw_rms, best.filtered)
