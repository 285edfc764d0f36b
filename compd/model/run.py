"""Running a compiled model: per tick for the daemon, vectorised over whole data files.

Both paths compute the same transposed-direct-form-II recursion (see
:mod:`compd.model.compiled`): ``step`` one sample at a time on Python floats,
``simulate`` as one ``lfilter`` per sub-model, operation by operation in the
same order. They agree to rounding (the sums over sub-models are in another
order); the tests hold them to 1e-9 on well-conditioned models. High-order
TFs with clustered slow poles (time constants of hours at 1 s) amplify
rounding in any polynomial form, and there the two agree to about 1e-4 relative.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from compd.errors import ModelError
from compd.model.compiled import CompiledModel, ModelState
from compd.model.dfilter import lfilter


class TickRunner:
    """Stateful per-tick evaluation: ``step(signals) -> outputs`` (um, a float per axis output).

    Position signals (Pahk 2002's slope terms) are read like any other signal,
    so a daemon that feeds the model its :attr:`CompiledModel.signals` each
    tick reads the axis position each tick with no change of its own.

    A tick is one sample of a few sub-models: it runs on Python floats, in
    the order :func:`simulate` (``lfilter``, :mod:`compd.model.dfilter`)
    evaluates the same recursion, so the two give the same numbers. numpy
    would do less arithmetic per call, but a daemon ticking once a second
    wakes with cold caches, where entering numpy costs tens of microseconds
    before any arithmetic (bench_tick's "cold" figure): 10 sub-models of 4th
    order take ~12 us warm here, and a third of the numpy step cold.
    """

    def __init__(self, compiled: CompiledModel, state: ModelState) -> None:
        compiled.check_state(state)
        self.compiled = compiled
        n_signals = len(compiled.signals)
        zero_slot, one_slot = n_signals, n_signals + 1  # CompiledModel.extended's constants
        owners = compiled.output_matrix.argmax(axis=0).tolist()
        self._gain = compiled.gain.copy()
        self._gains = self._gain.tolist()
        self._z: list[list[float]] = state.z.tolist()
        #: Per sub-model, what a tick reads of it (None: no minus signal, gate or position).
        self._subs: list[_Sub] = []
        for s in range(compiled.n_submodels):
            minus = int(compiled.minus_index[s])
            gate = int(compiled.gate_index[s])
            position = int(compiled.position_index[s])
            self._subs.append(
                _Sub(
                    plus=int(compiled.plus_index[s]),
                    reference=float(state.reference[s]),
                    minus=None if minus == zero_slot else minus,
                    gate=None
                    if gate == one_slot
                    else (
                        gate,
                        float(compiled.gate_sign[s]),
                        float(compiled.signed_threshold[s]),
                        bool(compiled.gate_on_input[s]),
                    ),
                    position=None
                    if position == one_slot
                    else (position, float(compiled.position_reference_mm[s])),
                    owner=owners[s],
                    b=compiled.b[s].tolist(),
                    a=compiled.a[s].tolist(),
                )
            )
        self._reference = state.reference.copy()
        self._n_outputs = len(compiled.output_names)
        self._gain_members: dict[str, np.ndarray] = {}
        for s, sub in enumerate(compiled.submodels):
            if sub.gain_name is not None:
                members = self._gain_members.get(sub.gain_name, np.zeros(0, dtype=np.intp))
                self._gain_members[sub.gain_name] = np.append(members, s)
        #: The named gains (``gain_name``) in use, the model file's own until :meth:`set_gains`.
        self.gains: dict[str, float] = {
            name: float(self._gain[members[0]]) for name, members in self._gain_members.items()
        }
        #: Each sub-model's contribution (um) at the last tick, gain and gate applied.
        self.contributions_um: list[float] = [0.0] * compiled.n_submodels
        # Swiss-lathe paper residual models: their door-feature state advances with each tick.
        self._residual = state.residual.copy()
        self._residuals = compiled.residual_slices()
        #: Each residual model's term (um) at the last tick, in ``compiled.residuals`` order.
        self.residual_terms = np.zeros(len(self._residuals))
        bias = compiled.bias_of(self._n_outputs)
        self._bias = None if bias is None else bias.tolist()

    @property
    def submodel_gains(self) -> np.ndarray:
        """The gain each sub-model's output is weighed by now (:meth:`set_gains` included)."""
        return self._gain.copy()

    @property
    def contributions(self) -> np.ndarray:
        """Each sub-model's contribution (um) at the last tick, as an array."""
        return np.array(self.contributions_um)

    @property
    def state(self) -> ModelState:
        """A snapshot of the current state (safe to persist while stepping goes on)."""
        compiled = self.compiled
        z = np.array(self._z, dtype=float).reshape(compiled.n_submodels, compiled.n_states)
        return ModelState(z, self._reference.copy(), self._residual.copy())

    def set_gains(self, gains: Mapping[str, float]) -> None:
        """Set named gains (``gain_name`` -> value) from the next :meth:`step` on.

        The filter states are left as they are: a gain weighs a sub-model's
        output (``y = W diag(g) y_sub``) and never enters its recursion, so a
        gain change moves the outputs by ``W diag(dg) y_sub`` at once and
        nothing else (ramp the gains to make that bumpless). Names not given
        keep their value.
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
        self._gains = self._gain.tolist()

    def step(self, signals: np.ndarray | Mapping[str, float] | Sequence[float]) -> list[float]:
        """Advance one sample and return the outputs (um) in ``compiled.output_names`` order.

        Non-finite signals are refused before the state is touched, so a bad
        reading can never poison the model.
        """
        compiled = self.compiled
        if type(signals) is dict or isinstance(signals, Mapping):  # the dict first: no ABC check
            try:
                values = list(map(float, map(signals.__getitem__, compiled.signals)))
            except KeyError:
                values = compiled.signal_vector(signals).tolist()  # raises, naming them
        else:
            values = np.asarray(signals, dtype=float).tolist()
            if len(values) != len(compiled.signals):
                raise ModelError(
                    f"model {compiled.name!r} needs {len(compiled.signals)} signal values "
                    f"({list(compiled.signals)}), got {len(values)}"
                )
        if not all(map(math.isfinite, values)):
            raise ModelError(
                f"non-finite signal value in {signals!r}; the state was left unchanged"
            )
        values += (0.0, 1.0)  # CompiledModel.extended's constant slots
        outputs = [0.0] * self._n_outputs
        contributions = self.contributions_um
        gains = self._gains
        for s, (sub, z) in enumerate(zip(self._subs, self._z, strict=True)):
            # The input as _submodel_response forms it, gated on the input where it says.
            u = values[sub.plus] - sub.reference
            if sub.minus is not None:
                u -= values[sub.minus]
            gate = sub.gate
            opened = True
            if gate is not None:
                index, sign, threshold, on_input = gate
                opened = values[index] * sign > threshold
                if on_input:
                    u *= opened
            # Transposed direct form II, operation by operation as compd.model.dfilter.
            b, a = sub.b, sub.a
            if z:
                y = z[0] + b[0] * u
                last = len(z) - 1
                for i in range(last):
                    z[i] = z[i + 1] + u * b[i + 1] - y * a[i + 1]
                z[last] = u * b[last + 1] - y * a[last + 1]
            else:
                y = u * b[0]
            if gate is not None and not gate[3]:
                y *= opened
            if sub.position is not None:
                y *= values[sub.position[0]] - sub.position[1]
            contributions[s] = contribution = y * gains[s]
            outputs[sub.owner] += contribution
        if self._residuals:
            dt_s = compiled.sample_time_s
            for r, (out_i, residual, part, signal_i) in enumerate(self._residuals):
                term = float(residual.step(self._residual[part], values[signal_i], dt_s))
                self.residual_terms[r] = term
                outputs[out_i] += term
        if self._bias is not None:
            outputs = [o + bias for o, bias in zip(outputs, self._bias, strict=True)]
        return outputs


@dataclass(frozen=True, slots=True)
class _Sub:
    """One sub-model as a tick reads it: indices into the extended signal values, its TF."""

    plus: int
    reference: float
    minus: int | None
    #: (signal index, sign, signed threshold, on the input)
    gate: tuple[int, float, float, bool] | None
    #: (signal index, reference mm)
    position: tuple[int, float] | None
    owner: int
    b: list[float]
    a: list[float]


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
