"""Running a compiled model: per tick for the daemon, vectorised over whole data files.

Both paths compute the same transposed-direct-form-II recursion (see
:mod:`compd.model.compiled`): ``step`` as one state-space matrix product per
tick, ``simulate`` as one ``lfilter`` per sub-model. They agree to rounding;
the tests hold them to 1e-9 on well-conditioned models. High-order TFs with
clustered slow poles (time constants of hours at 1 s) amplify rounding in any
polynomial form, and there the two agree to about 1e-4 relative.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from compd.errors import ModelError
from compd.model.compiled import CompiledModel, ModelState
from compd.model.dfilter import lfilter


def df2t_matrix(b: np.ndarray, a: np.ndarray) -> np.ndarray:
    """One matrix ``M`` with ``[z(k); y(k)] = M @ [z(k-1); u(k)]`` for all stacked DF2T filters.

    ``z`` is the (S, n) state flattened row by row, ``u`` and ``y`` hold one
    value per sub-model. From ``y = b0 u + z0`` and
    ``z'_i = b_{i+1} u - a_{i+1} y + z_{i+1}`` it follows that
    ``z'_i = (b_{i+1} - a_{i+1} b0) u - a_{i+1} z0 + z_{i+1}``.
    """
    n_subs, length = b.shape
    n = length - 1
    size = n_subs * n + n_subs
    matrix = np.zeros((size, size))
    for s in range(n_subs):
        base, u_col, y_row = s * n, n_subs * n + s, n_subs * n + s
        matrix[base : base + n, u_col] = b[s, 1:] - a[s, 1:] * b[s, 0]
        if n:
            matrix[base : base + n, base] = -a[s, 1:]
            matrix[base + np.arange(n - 1), base + np.arange(1, n)] += 1.0
            matrix[y_row, base] = 1.0
        matrix[y_row, u_col] = b[s, 0]
    return matrix


class TickRunner:
    """Stateful per-tick evaluation: ``step(signals) -> outputs`` (um, one per axis output).

    Position signals (Pahk 2002's slope terms) are read like any other signal,
    so a daemon that feeds the model its :attr:`CompiledModel.signals` each
    tick reads the axis position each tick with no change of its own.

    All sub-models advance together as one matrix-vector product
    (:func:`df2t_matrix`), so a tick costs a few small numpy operations
    whatever the number of sub-models, and no allocation of the state.
    """

    def __init__(self, compiled: CompiledModel, state: ModelState) -> None:
        compiled.check_state(state)
        self.compiled = compiled
        n_subs = compiled.n_submodels
        self._n_z = n_z = n_subs * compiled.n_states
        self._matrix = df2t_matrix(compiled.b, compiled.a)
        self._x = np.concatenate([state.z.ravel(), np.zeros(n_subs)])
        #: The inputs' part of ``_x``, written in place each tick.
        self._u = self._x[n_z:]
        self._reference = state.reference.copy()
        self._n_signals = n_signals = len(compiled.signals)
        self._extended = compiled.extended(np.zeros(n_signals))
        rows = np.arange(n_subs)
        n_extended = n_signals + 2  # the constant 0 and 1 slots (CompiledModel.extended)
        # u = extended[plus] - extended[minus] - reference, as one (S, signals + 2) product:
        # each row holds +1, -1 and -reference (on the constant-1 slot), so the sum is exact
        # up to its order (a last-bit difference from the three subtractions).
        self._inputs = np.zeros((n_subs, n_extended))
        self._inputs[rows, compiled.plus_index] += 1.0
        self._inputs[rows, compiled.minus_index] -= 1.0
        self._inputs[:, n_signals + 1] -= self._reference
        # The gate test (CompiledModel.gates_open) as one product: each row holds the sign on
        # its gate's slot (+1 on the constant-1 slot without a gate: always open), exact.
        self._gated = bool(np.any(compiled.gate_index < n_signals))
        self._gate_matrix = np.zeros((n_subs, n_extended))
        self._gate_matrix[rows, compiled.gate_index] = compiled.gate_sign
        self._input_ungated = ~compiled.gate_on_input
        self._gain = compiled.gain.copy()
        self._weighted_outputs = compiled.output_matrix * self._gain
        self._gain_members: dict[str, np.ndarray] = {}
        for s, sub in enumerate(compiled.submodels):
            if sub.gain_name is not None:
                members = self._gain_members.get(sub.gain_name, np.zeros(0, dtype=np.intp))
                self._gain_members[sub.gain_name] = np.append(members, s)
        #: The named gains (``gain_name``) in use, the model file's own until :meth:`set_gains`.
        self.gains: dict[str, float] = {
            name: float(self._gain[members[0]]) for name, members in self._gain_members.items()
        }
        # Models without slope terms skip the (all-ones) position factors.
        self._positioned = bool(np.any(compiled.position_index < n_signals))
        #: Each sub-model's contribution (um) at the last tick, gain and gate applied.
        self.contributions = np.zeros(n_subs)
        # Swiss-lathe paper residual models: their door-feature state advances with each tick.
        self._residual = state.residual.copy()
        self._residuals = compiled.residual_slices()
        #: Each residual model's term (um) at the last tick, in ``compiled.residuals`` order.
        self.residual_terms = np.zeros(len(self._residuals))
        self._bias = compiled.bias_of(len(compiled.output_names))

    @property
    def state(self) -> ModelState:
        """A snapshot of the current state (safe to persist while stepping goes on)."""
        compiled = self.compiled
        z = self._x[: self._n_z].reshape(compiled.n_submodels, compiled.n_states)
        return ModelState(z.copy(), self._reference.copy(), self._residual.copy())

    def set_gains(self, gains: Mapping[str, float]) -> None:
        """Set named gains (``gain_name`` -> value) from the next :meth:`step` on.

        The filter states are left as they are: a gain weighs a sub-model's
        output (``y = W diag(g) y_sub``) and never enters its recursion, so a
        gain change moves the outputs by ``W diag(dg) y_sub`` at once and
        nothing else (ramp the gains to make that bumpless). Names not given
        keep their value. Costs one (n_outputs, S) product.
        """
        for name, value in gains.items():
            members = self._gain_members.get(name)
            if members is None:
                raise ModelError(
                    f"model {self.compiled.name!r} has no gain named {name!r}; its gains are "
                    f"{sorted(self._gain_members) or 'none (no sub-model has a gain_name)'}"
                )
            if not np.isfinite(value):
                raise ModelError(f"gain {name!r} must be finite, got {value!r}")
        for name, value in gains.items():
            self._gain[self._gain_members[name]] = value
            self.gains[name] = float(value)
        self._weighted_outputs = self.compiled.output_matrix * self._gain

    def step(self, signals: np.ndarray | Mapping[str, float]) -> np.ndarray:
        """Advance one sample and return the outputs in ``compiled.output_names`` order.

        Non-finite signals are refused before the state is touched, so a bad
        reading can never poison the model.

        A tick after a sleep runs with cold caches, where each numpy call costs
        several microseconds whatever its size: the inputs, the gates and the
        recursion are a few products of matrices built once (``__init__``),
        and a mapping of signals is checked in plain Python.
        """
        compiled = self.compiled
        extended = self._extended
        if type(signals) is dict or isinstance(signals, Mapping):  # the dict first: no ABC check
            try:
                values = [signals[name] for name in compiled.signals]
            except KeyError:
                values = compiled.signal_vector(signals).tolist()  # raises, naming them
            finite = all(map(math.isfinite, values))
            if finite:
                extended[: self._n_signals] = values
        else:
            extended[: self._n_signals] = signals
            finite = bool(np.isfinite(extended).all())
        if not finite:
            raise ModelError(
                f"non-finite signal value in {signals!r}; the state was left unchanged"
            )
        u = self._u
        np.matmul(self._inputs, extended, out=u)
        opened = None
        if self._gated:
            opened = self._gate_matrix @ extended > compiled.signed_threshold
            u *= opened | self._input_ungated
        x = self._x
        advanced = self._matrix @ x
        x[: self._n_z] = advanced[: self._n_z]
        y = advanced[self._n_z :]
        if opened is not None:
            y *= opened | compiled.gate_on_input
        if self._positioned:
            y *= compiled.position_factors(extended)
        self.contributions = y * self._gain
        outputs: np.ndarray = self._weighted_outputs @ y
        if self._residuals:
            dt_s = compiled.sample_time_s
            for r, (out_i, residual, part, signal_i) in enumerate(self._residuals):
                term = residual.step(self._residual[part], extended[signal_i], dt_s)
                self.residual_terms[r] = term
                outputs[out_i] += term
        if self._bias is not None:
            outputs += self._bias
        return outputs


@dataclass(frozen=True, eq=False)
class SimulationResult:
    """Model outputs over a whole record.

    ``outputs``: (N, n_outputs) in um, residual models included;
    ``contributions``: (N, n_submodels) in um, gain, gate and position factor
    applied; ``residuals``: (N, n_residuals) in um, each residual model's term
    (Swiss-lathe paper); ``final_state``: the state after the last sample.
    """

    outputs: np.ndarray
    contributions: np.ndarray
    final_state: ModelState
    residuals: np.ndarray | None = None

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
    # A sum is finite when every term is (short of overflow, which the full test settles),
    # and costs no whole-record temporary.
    if not (np.isfinite(signals.sum()) or np.all(np.isfinite(signals))):
        raise ModelError("signals contain NaN or inf; repair the data before simulating")
    # One sub-model at a time from contiguous signal rows: the whole-record
    # (N, S) intermediates of a vectorised gather would triple peak memory.
    # The constant 0 / 1 slots of the extended vector are never materialised.
    rows = signals.T  # a view: each row is read once, strided or not, into a contiguous buffer
    n_samples = signals.shape[0]
    contributions = np.empty((compiled.n_submodels, n_samples))
    final_z = np.empty_like(state.z)

    def run_submodel(s: int) -> None:
        contributions[s], final_z[s] = _submodel_response(compiled, rows, state, s)

    # scipy's lfilter (the toolkit loads it: compd.model.dfilter) releases the GIL: long
    # records run their sub-models on every core.
    workers = min(compiled.n_submodels, os.cpu_count() or 1)
    if workers > 1 and n_samples * compiled.n_submodels >= _PARALLEL_MIN_SAMPLES:
        with ThreadPoolExecutor(workers) as pool:
            list(pool.map(run_submodel, range(compiled.n_submodels)))
    else:
        for s in range(compiled.n_submodels):
            run_submodel(s)
    outputs = (compiled.output_matrix @ contributions).T
    contributions = contributions.T
    # Swiss-lathe paper: each output's residual model on its door signal, added to the TF sum.
    slices = compiled.residual_slices()
    terms = np.empty((n_samples, len(slices)))
    final_residual = state.residual.copy()
    for r, (out_i, residual, part, signal_i) in enumerate(slices):
        terms[:, r], final_residual[part] = residual.simulate(
            rows[signal_i], compiled.sample_time_s, state.residual[part]
        )
        outputs[:, out_i] += terms[:, r]
    bias = compiled.bias_of(len(compiled.output_names))
    if bias is not None:
        outputs += bias
    final = ModelState(final_z, state.reference.copy(), final_residual)
    return SimulationResult(outputs, contributions, final, terms if slices else None)


#: Below this many samples x sub-models, threads cost more than they save.
_PARALLEL_MIN_SAMPLES = 200_000


def _submodel_response(
    compiled: CompiledModel, rows: np.ndarray, state: ModelState, s: int
) -> tuple[np.ndarray, np.ndarray]:
    """One sub-model's contribution over the record (um) and its final TF state.

    The constant 0 / 1 slots of the extended signal vector are never
    materialised: a sub-model without a minus signal, gate or position skips
    that step.
    """
    n_signals = len(compiled.signals)
    u = rows[compiled.plus_index[s]] - state.reference[s]
    if compiled.minus_index[s] < n_signals:
        u -= rows[compiled.minus_index[s]]
    # CompiledModel.gates_open's test, on one sub-model's row of the record.
    gate = (
        None
        if compiled.gate_index[s] >= n_signals
        else rows[compiled.gate_index[s]] * compiled.gate_sign[s] > compiled.signed_threshold[s]
    )
    if gate is not None and compiled.gate_on_input[s]:
        u *= gate
    if compiled.n_states:
        response, final_z = lfilter(compiled.b[s], compiled.a[s], u, zi=state.z[s])
    else:
        response, final_z = compiled.b[s, 0] * u, state.z[s].copy()
    if gate is not None and not compiled.gate_on_input[s]:
        response *= gate
    # CompiledModel.position_factors on one row (Pahk 2002's m1(T) * (P - P_ref)).
    if compiled.position_index[s] < n_signals:
        response *= rows[compiled.position_index[s]] - compiled.position_reference_mm[s]
    response *= compiled.gain[s]
    return response, final_z
