"""A measured displacement that does not start at zero: a probe not zeroed, or a file cut from a longer log.

compd takes every input as its change from the record's first value, so
every model predicts the displacement's change since the record's start: 0
there. A displacement logged as an absolute reading (a length gauge reading
12.3 um when the log began), or a file split off a longer log after the
machine had moved 8 um, starts far from 0. Fitted as logged, no gain can
carry the constant (the fit has no intercept: on a random machine of the
twin with 10 um added, the kept model fitted -74 % of its own calibration and
-1964 % of the next file); judged as logged, every model carries the offset
as error. Such a column is taken as its change from its first value, as the
inputs are, and the command says so.

A zeroed record's first value is one noisy sample near 0, so the test asks
for a first value well clear of both the record's own movement and its
sample-to-sample noise; the shared real record (first values 0.1-0.4 um,
ranges 22-89 um) stays as logged.
"""

from __future__ import annotations

import numpy as np

#: The first value must exceed this share of the column's range over the record ...
UNZEROED_RANGE_SHARE = 0.25
#: ... and this many times its sample-to-sample noise (robust standard deviation).
UNZEROED_NOISE_FACTOR = 5.0


def unzeroed_start(values: np.ndarray) -> float | None:
    """The first value of a displacement that was not zeroed at the record's start; None if it was."""
    values = np.asarray(values, dtype=float)
    if values.size < 2 or not np.isfinite(values[0]):
        return None
    start = float(values[0])
    steps = np.diff(values)
    # The median absolute deviation of the steps, as a standard deviation of one sample.
    noise = 1.4826 * float(np.median(np.abs(steps - np.median(steps)))) / np.sqrt(2.0)
    clear_of_range = abs(start) > UNZEROED_RANGE_SHARE * float(np.ptp(values))
    clear_of_noise = abs(start) > UNZEROED_NOISE_FACTOR * noise
    return start if clear_of_range and clear_of_noise else None
