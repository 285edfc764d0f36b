"""Running a compiled model: per tick for the daemon, vectorised over whole data files.

Both paths compute the same transposed-direct-form-II recursion (see
:mod:`compd.model.compiled`), so ``simulate`` over a file and ``step`` tick by
tick agree to rounding; the tests hold them to 1e-9.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import scipy.signal

from compd.errors import ModelError
from compd.model.compiled import CompiledModel, ModelState


class TickRunner:
    """Stateful per-tick evaluation: ``step(signals) -> outputs`` (um, one per axis output).

    The state lives in preallocated arrays updated in place, so a tick costs a
    dozen small numpy operations and no allocation of the state.
    """

    def __init__(self, compiled: CompiledModel, state: ModelState) -> None:
        compiled.check_state(state)
        self.compiled = compiled
        self._z = state.z.copy()
        self._reference = state.reference.copy()
        n_signals = len(compiled.signals)
        self._extended = compiled.extended(np.zeros(n_signals))
        self._n_signals = n_signals
        self._b0 = np.ascontiguousarray(compiled.b[:, 0])
        self._b_tail = np.ascontiguousarray(compiled.b[:, 1:])
        self._a_tail = np.ascontiguousarray(compiled.a[:, 1:])
        self._input_gated = compiled.gate_on_input
        self._output_gated = ~compiled.gate_on_input
        #: Each sub-model's contribution (um) at the last tick, gain and gate applied.
        self.contributions = np.zeros(compiled.n_submodels)

    @property
    def state(self) -> ModelState:
        """A snapshot of the current state (safe to persist while stepping goes on)."""
        return ModelState(self._z.copy(), self._reference.copy())

    def step(self, signals: np.ndarray | Mapping[str, float]) -> np.ndarray:
        """Advance one sample and return the outputs in ``compiled.output_names`` order.

        Non-finite signals are refused before the state is touched, so a bad
        reading can never poison the model.
        """
        compiled = self.compiled
        if isinstance(signals, Mapping):
            signals = compiled.signal_vector(signals)
        extended = self._extended
        extended[: self._n_signals] = signals
        if not np.isfinite(extended).all():
            raise ModelError(
                f"non-finite signal value in {signals!r}; the state was left unchanged"
            )
        u = extended[compiled.plus_index] - extended[compiled.minus_index] - self._reference
        gate = compiled.gates(extended)
        u *= np.where(self._input_gated, gate, 1.0)
        z = self._z
        y = self._b0 * u
        if z.shape[1]:
            y += z[:, 0]
            shifted = self._b_tail * u[:, None] - self._a_tail * y[:, None]
            shifted[:, :-1] += z[:, 1:]
            z[...] = shifted
        contributions = y * compiled.gain * np.where(self._output_gated, gate, 1.0)
        self.contributions = contributions
        outputs: np.ndarray = compiled.output_matrix @ contributions
        return outputs


@dataclass(frozen=True, eq=False)
class SimulationResult:
    """Model outputs over a whole record.

    ``outputs``: (N, n_outputs) in um; ``contributions``: (N, n_submodels) in
    um, gain and gate applied; ``final_state``: the state after the last sample.
    """

    outputs: np.ndarray
    contributions: np.ndarray
    final_state: ModelState

    def output(self, compiled: CompiledModel, name: str) -> np.ndarray:
        return self.outputs[:, compiled.output_names.index(name)]


def simulate(compiled: CompiledModel, signals: np.ndarray, state: ModelState) -> SimulationResult:
    """Run the model over ``signals`` (N, n_signals) starting from ``state`` (one ``lfilter`` per sub-model)."""
    compiled.check_state(state)
    signals = np.asarray(signals, dtype=float)
    if signals.ndim != 2 or signals.shape[1] != len(compiled.signals):
        raise ModelError(
            f"signals must be an (N, {len(compiled.signals)}) array in the order "
            f"{list(compiled.signals)}, got shape {signals.shape}"
        )
    if not np.all(np.isfinite(signals)):
        raise ModelError("signals contain NaN or inf; repair the data before simulating")
    extended = compiled.extended(signals)
    u = compiled.raw_inputs(extended) - state.reference
    gate = compiled.gates(extended)
    u *= np.where(compiled.gate_on_input, gate, 1.0)
    n_samples = signals.shape[0]
    responses = np.empty((n_samples, compiled.n_submodels))
    final_z = np.empty_like(state.z)
    for row in range(compiled.n_submodels):
        if compiled.n_states:
            responses[:, row], final_z[row] = scipy.signal.lfilter(
                compiled.b[row], compiled.a[row], u[:, row], zi=state.z[row]
            )
        else:
            responses[:, row] = compiled.b[row, 0] * u[:, row]
    contributions = responses * compiled.gain * np.where(compiled.gate_on_input, 1.0, gate)
    outputs = contributions @ compiled.output_matrix.T
    return SimulationResult(outputs, contributions, ModelState(final_z, state.reference.copy()))
