"""What a probe is regressed on: an output's columns, the regressors kept tick by tick, the probed output.

:func:`output_columns` names the sub-models whose contributions make an
output's regressor ``x`` (then 1: the bias); :class:`KeptRows` keeps those
regressors over the last hours, so that a probe typed in late still finds
the regressor of its touch instant; :func:`probed_thermal_error_um` is the
one place where what a probe measures becomes what the model predicts.
:class:`~compd.model.probelearner.OutputLearner` uses all three. numpy only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from compd.errors import ModelError
from compd.model.compiled import CompiledModel

__all__ = [
    "DEFAULT_KEEP_S",
    "DEFAULT_ROW_EVERY_S",
    "KeptRows",
    "RegressorWindow",
    "output_columns",
    "probed_thermal_error_um",
]

#: The daemon keeps one regressor row per this many seconds ...
DEFAULT_ROW_EVERY_S = 60.0
#: ... over this long: a touch older than this is refused (a shift's gauge results typed in late).
DEFAULT_KEEP_S = 12 * 3600.0


def output_columns(compiled: CompiledModel, output: str) -> tuple[np.ndarray, tuple[str, ...]]:
    """``output``'s sub-models: their columns in the model's contributions, and their names.

    The regressor of a tick is ``x = (contributions[columns], 1)``; the
    names, then :data:`~compd.model.updateprior.BIAS`, are the prior's
    parameters (:func:`compd.files.probeprior.output_prior`).
    """
    if output not in compiled.output_names:
        raise ModelError(f"model {compiled.name!r} has no output {output!r}")
    columns = np.flatnonzero(compiled.output_matrix[compiled.output_names.index(output)])
    names = tuple(compiled.submodels[int(s)].name for s in columns)
    return columns, names


def probed_thermal_error_um(residue_um: float, offset_um: float, sign: float) -> float:
    """The thermal error the model predicts, from what a probe measures with compensation active.

    The machine applies the offset compd writes to the tool centre point
    (:mod:`compd.sim.plc.machine`)::

        residue_um = e_um + offset_um,    offset_um = sign * y_um   (compd.service.loop.compensator)

    where ``e_um`` is the axis's thermal error and ``y_um`` the model's
    output: compensation is perfect when ``e_um = -sign * y_um``. So the
    output the model should have given is::

        y_um = -sign * e_um = sign * (offset_um - residue_um)

    (``sign`` = -1, the default: ``y_um = residue_um - offset_um``, the residue
    plus the correction in force). ``residue_um``: the probe's deviation
    along the axis, the same sense as the axis's offset; ``offset_um``: the
    offset in force at the touch instant, in um as written to the PLC
    (before the point's ``scale``); ``sign``: the axis's ``sign`` (+-1).
    Without compensation (offset 0) the residue is the thermal error itself.
    """
    if sign not in (-1.0, 1.0):
        raise ModelError(f"an axis sign is +1 or -1, not {sign!r}")
    if not (math.isfinite(residue_um) and math.isfinite(offset_um)):
        raise ModelError(
            f"a probe's residue ({residue_um!r} um) and the offset in force ({offset_um!r} um) "
            "must be finite"
        )
    return float(sign * (offset_um - residue_um))


@dataclass(frozen=True)
class RegressorWindow:
    """How the regressors are kept: one row per ``row_every_s`` bin (0: every tick) over ``keep_s``."""

    row_every_s: float = DEFAULT_ROW_EVERY_S
    keep_s: float = DEFAULT_KEEP_S

    def __post_init__(self) -> None:
        if not (self.row_every_s >= 0.0 and self.keep_s > 0.0):
            raise ModelError(
                f"regressor window: row_every_s must be >= 0 and keep_s above 0, are "
                f"{self.row_every_s!r} and {self.keep_s!r}"
            )


class KeptRows:
    """Time-ordered rows ``(t_s, x, fixed_um)`` in one growing array, the oldest dropped past ``keep_s``.

    Appending is amortised O(p): the live rows are moved to the front only
    when the array is full, and the array doubles only when more than half
    of it is live.
    """

    def __init__(self, p: int, keep_s: float, capacity: int = 64) -> None:
        self.keep_s = keep_s
        self.t_s = np.empty(capacity)
        self.x = np.empty((capacity, p))
        self.fixed_um = np.empty(capacity)
        self.lo = self.hi = 0

    def __len__(self) -> int:
        return self.hi - self.lo

    def append(self, t_s: np.ndarray, x: np.ndarray, fixed_um: np.ndarray) -> None:
        n = len(t_s)
        if self.hi + n > len(self.t_s):
            live = len(self)
            size = len(self.t_s)
            while live + n > size // 2:
                size *= 2
            for name in ("t_s", "x", "fixed_um"):
                old = getattr(self, name)
                new = np.empty((size, *old.shape[1:]))
                new[:live] = old[self.lo : self.hi]
                setattr(self, name, new)
            self.lo, self.hi = 0, live
        self.t_s[self.hi : self.hi + n] = t_s
        self.x[self.hi : self.hi + n] = x
        self.fixed_um[self.hi : self.hi + n] = fixed_um
        self.hi += n
        if math.isfinite(self.keep_s):
            oldest = self.t_s[self.hi - 1] - self.keep_s
            self.lo += int(np.searchsorted(self.t_s[self.lo : self.hi], oldest, side="left"))

    def view(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        part = slice(self.lo, self.hi)
        return self.t_s[part], self.x[part], self.fixed_um[part]
