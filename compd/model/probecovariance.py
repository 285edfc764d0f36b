"""The probe update's parameter covariance, kept so one probe costs one pass over it (issue 42).

``P = stored + drift_weight * P0``: the random walk's drift between probes is
the prior's shape ``P0`` times a scalar (:mod:`compd.model.probeupdate`), so
it is kept as that scalar, and a measurement update changes ``stored``
alone, by one rank-one product: ``P - v v'`` is ``stored - v v' + w P0``.

At a few hundred parameters the cost of a probe is memory, not arithmetic: a
new p x p array costs a page fault per 4 KB on first touch (about 1 ms at
401 parameters on a virtual machine, ten times the update itself). So the
arrays are made once and reused: a scratch array for ``v v'``, and a second
copy that keeps the state a :meth:`snapshot` asked for, written by the first
change after it instead of copied beforehand (double buffering).

numpy only.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["DriftingCovariance"]

#: Each state of every covariance gets its own number: a state put back never shares one with
#: a state that was dropped.
_versions = itertools.count(1)
#: A rank-one step with an element beyond this would overflow (its square beyond float's range).
_LARGEST_STEP = 1e150


@dataclass
class DriftingCovariance:
    """``stored + drift_weight * prior``, changed in place; :meth:`snapshot` / :meth:`put_back` undo."""

    prior: np.ndarray
    stored: np.ndarray
    drift_weight: float = 0.0
    _version: int = field(default_factory=lambda: next(_versions))
    _scratch: np.ndarray | None = field(default=None, repr=False)
    #: The state of version ``_kept_version``, when a snapshot asked to keep it (else a spare).
    _kept: np.ndarray | None = field(default=None, repr=False)
    _kept_version: int = -1
    _protected_version: int = -1
    #: ``(x, version, stored @ x, prior @ x)`` of the last regressor asked about: a probe asks
    #: for ``P x`` three times (flag, weight, update) with the same array.
    _products: tuple[np.ndarray, int, np.ndarray, np.ndarray] | None = field(
        default=None, repr=False
    )

    @classmethod
    def of(cls, matrix: np.ndarray, prior: np.ndarray) -> DriftingCovariance:
        """A covariance equal to ``matrix`` (copied), drifting in the shape of ``prior``."""
        return cls(prior, np.array(matrix, dtype=float))

    def matrix(self) -> np.ndarray:
        """``P`` as a new array."""
        if self.drift_weight == 0.0:
            return self.stored.copy()
        matrix: np.ndarray = self.stored + self.drift_weight * self.prior
        return matrix

    def times(self, x: np.ndarray) -> np.ndarray:
        """``P x``, without forming ``P``."""
        stored_x, prior_x = self._times(x)
        px: np.ndarray = stored_x + self.drift_weight * prior_x
        return px

    def prior_quadratic(self, x: np.ndarray) -> float:
        """``x' P0 x``."""
        return float(x @ self._times(x)[1])

    def _times(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        products = self._products
        if products is None or products[0] is not x or products[1] != self._version:
            products = (x, self._version, self.stored @ x, self.prior @ x)
            self._products = products
        return products[2], products[3]

    def downdate(self, v: np.ndarray) -> None:
        """``P -= v v'``; a ``v`` that is not finite or would overflow raises ValueError, nothing changed."""
        if not (np.all(np.isfinite(v)) and float(np.max(np.abs(v), initial=0.0)) < _LARGEST_STEP):
            raise ValueError("the update's step is not a finite number")
        if self._scratch is None or self._scratch.shape != self.stored.shape:
            self._scratch = np.empty_like(self.stored)
        np.einsum("i,j->ij", v, v, out=self._scratch)
        if self._must_keep():  # the new state into the spare, the kept one stays where it is
            kept = self._spare()
            np.subtract(self.stored, self._scratch, out=kept)
            self.stored, self._kept = kept, self.stored
            self._kept_version = self._version
        else:
            np.subtract(self.stored, self._scratch, out=self.stored)
        self._changed()

    def add_to_last(self, variance: float) -> None:
        """``P[-1, -1] += variance`` (the bias's variance widened)."""
        if not math.isfinite(variance):
            raise ValueError("a widening that is not a finite number")
        if self._must_keep():
            kept = self._spare()
            np.copyto(kept, self.stored)
            self._kept, self._kept_version = kept, self._version
        self.stored[-1, -1] += variance
        self._changed()

    def snapshot(self) -> int:
        """A token for this state, which :meth:`put_back` restores until the state after the next
        snapshot is asked for: snapshots may nest while nothing changes between them."""
        self._protected_version = self._version
        return self._version

    def put_back(self, token: int) -> None:
        if token == self._version:
            return
        if token != self._kept_version or self._kept is None:
            raise RuntimeError("a probe update's snapshot was taken before a later one")
        self.stored, self._kept = self._kept, self.stored
        self._version, self._kept_version = token, -1

    def finite(self) -> bool:
        """Whether ``P`` is finite: every change is checked on its way in (:meth:`downdate`,
        :meth:`add_to_last`), so only the scalar is left to check."""
        return math.isfinite(self.drift_weight)

    def _must_keep(self) -> bool:
        return self._protected_version == self._version and self._kept_version != self._version

    def _spare(self) -> np.ndarray:
        if self._kept is None or self._kept.shape != self.stored.shape:
            self._kept = np.empty_like(self.stored)
        self._kept_version = -1
        return self._kept

    def _changed(self) -> None:
        self._version = next(_versions)
