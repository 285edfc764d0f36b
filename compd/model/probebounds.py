"""The bounds a probe learner's state keeps, checked as it is read back: a state is input like any other.

What :meth:`compd.model.probelearner.OutputLearner.restore` refuses beyond
shapes and finite numbers (issue 41 item 6): a gain off its rails, a bias no
update reaches, a covariance that is not positive definite or a million times
wider than its prior, a time in the future. numpy only: no files, no logging.
"""

from __future__ import annotations

import math

import numpy as np

from compd.errors import ModelError
from compd.model.probesettings import ProbeSettings, max_probe_um, parameter_bounds
from compd.model.updateprior import Prior

#: A restored state's times may be this far after the reader's clock (s): a touch time may
#: be a minute ahead of the daemon's (the PLC's clock), no more.
RESTORE_SKEW_S = 120.0
#: ... and this far on a simulation's clock (virtual or sped up: it runs ahead of the wall, and
#: the next run starts from the wall again), the longest simulation.
SIMULATED_SKEW_S = 14 * 24 * 3600.0
#: A restored parameter's variance may be at most this many times its prior's: the random
#: walk widens it between probes, never by a million.
MAX_VARIANCE_GROWTH = 1e6


def check_bounds(
    prior: Prior,
    settings: ProbeSettings,
    theta: np.ndarray,
    covariance: np.ndarray,
    accepted_shift_um: float,
) -> None:
    """The bounds a state reached by updates keeps (see :meth:`OutputLearner.restore`)."""
    lows, highs = parameter_bounds(prior, settings)
    what = "gain" if prior.form == "gains" else "coefficient"
    for name, value, low, high in zip(prior.names[:-1], theta[:-1], lows, highs, strict=True):
        slack = 1e-9 * max(1.0, abs(low), abs(high))
        if not low - slack <= value <= high + slack:
            raise ModelError(
                f"the {what} of {name} is {value:g}, beyond its rails [{low:g}, {high:g}]"
            )
    # Twice the bound (or what a person accepted): a state learned under a larger
    # probes.max_shift_um is not set aside for that alone.
    bias_bound = 2.0 * min(max(settings.max_shift_um, accepted_shift_um), max_probe_um(prior))
    if abs(theta[-1] - prior.mean[-1]) > bias_bound:
        raise ModelError(
            f"the bias is {theta[-1]:g} um, beyond {bias_bound:g} um (twice the learned "
            "shift's bound, max_shift_um, or what a person accepted): no update reaches it"
        )
    widest = MAX_VARIANCE_GROWTH * np.diag(prior.covariance)
    widest[-1] += max_probe_um(prior) ** 2
    variances = np.diag(covariance)
    if np.any(variances > widest):
        i = int(np.argmax(variances / widest))
        raise ModelError(
            f"the variance of {prior.names[i]} is {variances[i]:g}, beyond {widest[i]:g} "
            "(a million times its prior's): no update reaches it"
        )
    # Positive semi-definite: a member of the bank that holds the coefficients has 0 there.
    smallest = float(np.linalg.eigvalsh(covariance).min())
    if not smallest >= -1e-9 * max(1.0, float(np.abs(np.diag(covariance)).max())):
        raise ModelError("covariance is not positive semi-definite")


def number(value: object, key: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ModelError(f"{key} is {value!r}, not a finite number")
    return float(value)


def time_or_none(value: object, key: str) -> float | None:
    return None if value is None else number(value, key)


def array_of(value: object, shape: tuple[int, ...], key: str) -> np.ndarray:
    try:
        array = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ModelError(f"{key} is not an array of numbers") from None
    if array.shape != shape:
        raise ModelError(f"{key} has shape {array.shape}, needs {shape}")
    if not np.all(np.isfinite(array)):
        raise ModelError(f"{key} has a value that is not a finite number")
    return array
