"""The thermal zero a model starts from: its inputs' references at the daemon's start.

A fitted model keeps its calibration's first values as fixed references
(absolute, not "value at start"), and names the shop-air input whose change
since then moves the temperatures' zero (:class:`~compd.model.structure.AmbientZero`:
a cold machine sits at today's air temperature). Started without a saved
state, the daemon takes each sub-model to the steady state for the current
inputs relative to that zero, so the drift of a machine that is already warm
is compensated at once.

A machine whose every moved temperature reads within :data:`COLD_BAND_DEGC`
of that zero cannot be told from a cold one: the difference is as large as
two class-A Pt100 offsets (IEC 60751, ``±(0.15 + 0.002 |T|)`` degC each, up
to 0.4 degC apart) plus a coolant a little warmer or colder than on the
calibration day. It is taken as cold, and today's readings become its zero:
they carry today's sensor offsets, which the calibration's zero does not. On
the twin (cold starts of five shifts of other seeds than the calibration's)
the worst temperature read 0.2-0.55 degC off its zero at rest, and 2.5 degC or
more 5 minutes into a shift.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from compd.model.compiled import CompiledModel

#: A machine whose moved temperatures all read this close to their zero is taken as cold (degC).
COLD_BAND_DEGC = 0.8


def start_references(compiled: CompiledModel, vector: np.ndarray) -> tuple[np.ndarray, bool]:
    """Each sub-model's reference for a start at signal values ``vector``, and whether it read cold.

    Fixed references, those of the ambient's ``moves`` shifted by the
    ambient's change from its reference; "value at start" ones (NaN) from
    ``vector``; the moved ones from ``vector`` too when the machine reads cold
    (module docstring).
    """
    at_start: np.ndarray = compiled.raw_inputs(compiled.extended(vector))
    fixed = compiled.fixed_reference
    if compiled.ambient_index < 0:
        return np.where(np.isnan(fixed), at_start, fixed), False
    moves = compiled.ambient_moves & np.isfinite(fixed)
    fixed = fixed + moves * (vector[compiled.ambient_index] - compiled.ambient_reference)
    cold = bool(moves.any()) and bool(
        np.max(np.abs(at_start[moves] - fixed[moves])) < COLD_BAND_DEGC
    )
    from_now = np.isnan(fixed) | (moves & cold)  # a power or speed keeps its zero even then
    return np.where(from_now, at_start, fixed), cold
