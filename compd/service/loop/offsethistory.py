"""The offset in force per axis, tick by tick, for a probe's touch instant (a gauge result typed in late).

What a probe measures with compensation on is the residue; the thermal error
the model should have predicted is the residue plus the offset in force when
the probe touched (:func:`compd.model.proberegressors.probed_thermal_error_um`),
so the loop keeps that offset over :data:`OFFSET_HISTORY_S`.
"""

from __future__ import annotations

import numpy as np

from compd.errors import ModelError

#: The offset in force is kept per tick over this long (s): a gauge result typed in hours late.
OFFSET_HISTORY_S = 12 * 3600.0


class OffsetHistory:
    """The offset in force per tick (um) over :data:`OFFSET_HISTORY_S`, for a probe's touch instant.

    Two float arrays (16 bytes a tick, at most 4 times the rows kept: 2 MB for 12 h at
    1 Hz), the oldest rows dropped when the arrays fill, so appending is amortised O(1).
    """

    def __init__(self, capacity: int = 1024) -> None:
        self.t_s = np.empty(capacity)
        self.offset_um = np.empty(capacity)
        self.lo = self.hi = 0

    def append(self, t_s: float, offset_um: float) -> None:
        if self.hi == len(self.t_s):
            self.lo += int(np.searchsorted(self.t_s[self.lo : self.hi], t_s - OFFSET_HISTORY_S))
            live = self.hi - self.lo
            if live > len(self.t_s) // 2:  # mostly live: grow
                self.t_s = np.concatenate([self.t_s, np.empty(len(self.t_s))])
                self.offset_um = np.concatenate([self.offset_um, np.empty(len(self.offset_um))])
            self.t_s[:live] = self.t_s[self.lo : self.hi]
            self.offset_um[:live] = self.offset_um[self.lo : self.hi]
            self.lo, self.hi = 0, live
        self.t_s[self.hi] = t_s
        self.offset_um[self.hi] = offset_um
        self.hi += 1

    def at(self, t_s: float) -> float:
        times = self.t_s[self.lo : self.hi]
        if not times.size:
            raise ModelError("no offset is known yet: the probe came before the first tick")
        if t_s < max(times[0], times[-1] - OFFSET_HISTORY_S):
            raise ModelError(
                f"the touch is older than the offsets kept ({OFFSET_HISTORY_S / 3600:g} h): probe again"
            )
        return float(np.interp(t_s, times, self.offset_um[self.lo : self.hi]))
