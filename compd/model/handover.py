"""Starting a model that replaces a running one mid-shift: warm, not cold.

A model switched in by ``compd model load`` while the machine is warm must
not start as if the machine were cold (its inputs taken as changes from
*now*) nor in equilibrium with the inputs of this instant (a spindle that
happens to cut right now has not cut for ever). Instead:

1. every sub-model is run over the recent history of the inputs the daemon
   keeps (:class:`SignalHistory`), from equilibrium with its first row, so
   it ends in the state that history leaves it in;
2. a sub-model the running model has too (same name, same TF, same inputs:
   what ``compd extend`` and ``compd update`` keep) takes over the running
   one's state and reference exactly, so the common part does not move.
"""

from __future__ import annotations

import itertools
import math
from array import array
from collections.abc import Mapping

import numpy as np

from compd.model.compiled import CompiledModel, ModelState, qualified_names
from compd.model.run import simulate


class SignalHistory:
    """The last ``capacity`` ticks of every signal, oldest first on read (a ring buffer).

    Kept in single precision: 7 significant digits (1 mdegC at 1,000 degC, 1 rpm in
    10 million) are far finer than any sensor, and 8 h of 6 signals at 1 s take
    0.7 MB of the daemon's memory instead of 1.4 MB. Read back as doubles.
    """

    def __init__(self, names: tuple[str, ...] | list[str], capacity: int) -> None:
        self.names = tuple(names)
        self._index = {name: i for i, name in enumerate(self.names)}
        # A flat array of C floats, written a row at a time without numpy (a tick's call into
        # numpy costs tens of microseconds with cold caches), read as a numpy view.
        self._flat = array("f", [math.nan]) * (max(1, capacity) * len(self.names))
        self._rows = np.frombuffer(self._flat, dtype=np.float32).reshape(
            max(1, capacity), len(self.names)
        )
        self._next = 0
        self._count = 0

    def __len__(self) -> int:
        return self._count

    def append(self, values: Mapping[str, float]) -> None:
        width = len(self.names)
        if width:  # (an empty slice of an array numpy views counts as a resize)
            start = self._next * width
            row = array("f", map(values.get, self.names, itertools.repeat(math.nan)))
            self._flat[start : start + width] = row
        self._next = (self._next + 1) % len(self._rows)
        self._count = min(self._count + 1, len(self._rows))

    def matrix(self, names: tuple[str, ...]) -> np.ndarray:
        """``(ticks, len(names))`` in time order, from the first row where every name is finite;
        later gaps (a faulted input) are filled with the last finite value."""
        full = self._count == len(self._rows)
        rows = np.roll(self._rows, -self._next, axis=0) if full else self._rows[: self._count]
        columns = rows[:, [self._index[name] for name in names]].astype(float)
        complete = np.flatnonzero(np.isfinite(columns).all(axis=1))
        if complete.size == 0:
            return np.empty((0, len(names)))
        columns = columns[complete[0] :]
        for j in range(columns.shape[1]):
            column = columns[:, j]
            bad = ~np.isfinite(column)
            if bad.any():
                last = np.maximum.accumulate(np.where(bad, 0, np.arange(column.size)))
                columns[:, j] = column[last]
        return columns


def handover_state(
    new: CompiledModel,
    history: np.ndarray,
    running: CompiledModel | None = None,
    running_state: ModelState | None = None,
) -> ModelState:
    """The state ``new`` starts with when it replaces ``running`` (see the module docstring).

    ``history`` is ``(ticks, len(new.signals))`` at ``new``'s sample time,
    its last row the current values.
    """
    state = new.steady_state(history[0])
    if len(history) > 1:
        state = simulate(new, history[1:], state).final_state
    if running is None or running_state is None:
        return state
    z, reference = state.z.copy(), state.reference.copy()
    theirs = {name: i for i, name in enumerate(qualified_names(running))}
    for s, name in enumerate(qualified_names(new)):
        r = theirs.get(name)
        if r is not None and _same_dynamics(new, s, running, r):
            # Rows are zero-padded to each model's longest TF; the padding's states stay 0.
            n = min(z.shape[1], running_state.z.shape[1])
            z[s] = 0.0
            z[s, :n] = running_state.z[r, :n]
            reference[s] = running_state.reference[r]
    return ModelState(z, reference, state.residual)


def _same_dynamics(a: CompiledModel, s: int, b: CompiledModel, r: int) -> bool:
    """Same TF at the same sample time, fed by the same signals the same way."""

    def signal(model: CompiledModel, index: int) -> str | None:
        return model.signals[index] if index < len(model.signals) else None

    return (
        a.sample_time_s == b.sample_time_s
        and np.array_equal(np.trim_zeros(a.b[s], "b"), np.trim_zeros(b.b[r], "b"))
        and np.array_equal(np.trim_zeros(a.a[s], "b"), np.trim_zeros(b.a[r], "b"))
        and signal(a, a.plus_index[s]) == signal(b, b.plus_index[r])
        and signal(a, a.minus_index[s]) == signal(b, b.minus_index[r])
        and signal(a, a.gate_index[s]) == signal(b, b.gate_index[r])
        and np.array_equal(a.fixed_reference[s], b.fixed_reference[r], equal_nan=True)
        and a.gate_threshold[s] == b.gate_threshold[r]
        and a.gate_sign[s] == b.gate_sign[r]
    )
