"""Compilation: a model becomes flat arrays once, at load, so a tick is a few array operations.

Every sub-model is brought to the run sample time (continuous parts by
zero-order hold, discrete parts converted exactly when the rate differs; or
taken as the model file's precompiled difference equations at that period,
:mod:`compd.model.precompiled`, which is all the daemon does),
normalised so ``a0 == 1``, checked for stability, and padded to a common
length ``L`` so all sub-models advance together in transposed direct form II
(the form ``scipy.signal.lfilter`` uses, so its ``zi`` *is* compd's state)::

    y(k)       = b0 u(k) + z0(k-1)
    z_i(k)     = b_{i+1} u(k) - a_{i+1} y(k) + z_{i+1}(k-1)

Signals are gathered by index into an extended signal vector whose last two
slots hold the constants 0 (for "no minus signal") and 1 (for "no gate",
"no position"). A position multiplier (Pahk 2002 eq. 5, ``m1(T) * P``)
scales each sub-model's output by ``extended[position_index] -
position_reference_mm``, which is ``1 - 0`` for sub-models without one; it
scales the output, never the TF's state, so steady and rest states do not
depend on it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np

from compd.errors import ModelError
from compd.model.dfilter import lfilter
from compd.model.limits import (
    CHECK_SAMPLES,
    MAX_GAIN_UM_PER_UNIT,
    MAX_SAMPLE_TIME_S,
    MAX_STATES,
    MAX_SUBMODELS,
)
from compd.model.precompiled import DifferenceEquations, runnable_tf, stored_at
from compd.model.residual import ResidualModel
from compd.model.structure import GateTarget, Model, SubModel
from compd.model.transfer import DiscreteTF
from compd.model.zero import start_references


@dataclass(frozen=True, eq=False)
class ModelState:
    """Everything a running model remembers: TF states and input references.

    ``z`` has one row per sub-model (DF2T delay line, ``lfilter``'s ``zi``);
    ``reference`` is each sub-model's input reference (for "value at start"
    sub-models, the value captured when the model started); ``residual`` the
    door-feature states of the outputs' residual models (Swiss-lathe paper), end to
    end in output order (empty without them).
    """

    z: np.ndarray
    reference: np.ndarray
    residual: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def to_dict(self) -> dict[str, list[list[float]] | list[float]]:
        """Plain lists, for JSON/YAML persistence (``residual`` only when there is one)."""
        data: dict[str, list[list[float]] | list[float]] = {
            "z": self.z.tolist(),
            "reference": self.reference.tolist(),
        }
        if self.residual.size:
            data["residual"] = self.residual.tolist()
        return data

    @classmethod
    def from_dict(cls, data: Mapping[str, object]) -> ModelState:
        try:
            z = np.asarray(data["z"], dtype=float)
            reference = np.asarray(data["reference"], dtype=float)
            residual = np.asarray(data.get("residual", []), dtype=float).reshape(-1)
        except (KeyError, TypeError, ValueError) as exc:
            raise ModelError(
                f"saved model state is malformed ({exc}); expected keys z, reference"
            ) from exc
        return cls(z=z, reference=reference, residual=residual)


@dataclass(frozen=True, eq=False)
class CompiledModel:
    """A model as flat arrays at one sample time. Build with :func:`compile_model`."""

    name: str
    sample_time_s: float
    signals: tuple[str, ...]
    output_names: tuple[str, ...]
    submodels: tuple[SubModel, ...]
    submodel_paths: tuple[str, ...]
    discrete: tuple[DiscreteTF, ...]
    b: np.ndarray  # (S, L) numerators, a0-normalised, delay folded in
    a: np.ndarray  # (S, L) denominators, a[:, 0] == 1
    plus_index: np.ndarray  # (S,) index into the extended signal vector
    minus_index: np.ndarray  # (S,) index, or the constant-0 slot
    fixed_reference: np.ndarray  # (S,) NaN where the reference is the value at start
    gate_index: np.ndarray  # (S,) index, or the constant-1 slot
    gate_threshold: np.ndarray  # (S,)
    gate_sign: np.ndarray  # (S,) +1 active above threshold, -1 active below
    gate_on_input: np.ndarray  # (S,) bool
    gain: np.ndarray  # (S,)
    position_index: np.ndarray  # (S,) index of the position signal, or the constant-1 slot
    position_reference_mm: np.ndarray  # (S,) subtracted from the position; 0 without one
    output_matrix: np.ndarray  # (n_outputs, S) 0/1: which sub-models sum into which output
    #: The shop-air signal's index and reference (:class:`~compd.model.structure.AmbientZero`):
    #: at start the fixed references where ``ambient_moves`` shift by its difference from it.
    ambient_index: int = -1  # -1: none
    ambient_reference: float = 0.0
    ambient_moves: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    #: Swiss-lathe paper residual models: (output index, model), added to that output's TF sum.
    residuals: tuple[tuple[int, ResidualModel], ...] = ()
    #: Per output, a constant added to it (um): the bias probes taught (``model export --updated``).
    output_bias_um: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def bias_of(self, n_outputs: int) -> np.ndarray | None:
        """:attr:`output_bias_um` when one is not 0, else None (the common case adds nothing)."""
        bias = self.output_bias_um
        return bias if bias.shape == (n_outputs,) and np.any(bias != 0.0) else None

    @property
    def residual_state_size(self) -> int:
        return sum(r.features.state_size for _, r in self.residuals)

    def residual_slices(self) -> list[tuple[int, ResidualModel, slice, int]]:
        """Per residual: output index, model, its slice of ``ModelState.residual``, signal index."""
        found, start = [], 0
        for out_i, residual in self.residuals:
            size = residual.features.state_size
            found.append(
                (out_i, residual, slice(start, start + size), self.signals.index(residual.signal))
            )
            start += size
        return found

    def _residual_state(self, vector: np.ndarray) -> np.ndarray:
        parts = [r.features.initial_state(vector[i]) for _, r, _, i in self.residual_slices()]
        return np.concatenate(parts) if parts else np.zeros(0)

    @cached_property
    def signed_threshold(self) -> np.ndarray:
        """``gate_threshold * gate_sign``, the right-hand side of the gate test."""
        signed: np.ndarray = self.gate_threshold * self.gate_sign
        return signed

    @property
    def n_submodels(self) -> int:
        return int(self.b.shape[0])

    @property
    def n_states(self) -> int:
        """DF2T delay-line length per sub-model (``L - 1``)."""
        return int(self.b.shape[1]) - 1

    def extended(self, signals: np.ndarray) -> np.ndarray:
        """Signal values (last axis in :attr:`signals` order) with the constant 0 and 1 slots appended."""
        signals = np.asarray(signals, dtype=float)
        constants = np.broadcast_to([0.0, 1.0], (*signals.shape[:-1], 2))
        return np.concatenate([signals, constants], axis=-1)

    def signal_vector(self, values: Mapping[str, float]) -> np.ndarray:
        """Signal values in :attr:`signals` order from a name -> value mapping."""
        missing = [name for name in self.signals if name not in values]
        if missing:
            raise ModelError(f"model {self.name!r} needs signals {missing} that were not given")
        return np.array([values[name] for name in self.signals], dtype=float)

    def raw_inputs(self, extended: np.ndarray) -> np.ndarray:
        """``signal - minus`` per sub-model (before the reference is removed)."""
        difference: np.ndarray = extended.take(self.plus_index, axis=-1) - extended.take(
            self.minus_index, axis=-1
        )
        return difference

    def gates_open(self, extended: np.ndarray) -> np.ndarray:
        """True where each sub-model's gate is open (always, for sub-models without a gate).

        ``value * sign > threshold * sign`` is ``value > threshold`` for an
        'above' gate and ``value < threshold`` for a 'below' gate.
        """
        opened: np.ndarray = (
            extended.take(self.gate_index, axis=-1) * self.gate_sign > self.signed_threshold
        )
        return opened

    def position_factors(self, extended: np.ndarray) -> np.ndarray:
        """``position - reference_mm`` per sub-model (mm), 1 for sub-models without a position."""
        factors: np.ndarray = (
            extended.take(self.position_index, axis=-1) - self.position_reference_mm
        )
        return factors

    def check_state(self, state: ModelState) -> None:
        """Refuse a state that belongs to a different model structure."""
        expected = (self.n_submodels, self.n_states)
        if state.z.shape != expected or state.reference.shape != (self.n_submodels,):
            raise ModelError(
                f"state has shape z{state.z.shape}/reference{state.reference.shape} but model "
                f"{self.name!r} needs z{expected}/reference({self.n_submodels},): it was saved "
                "by a different model"
            )
        if state.residual.shape != (self.residual_state_size,):
            raise ModelError(
                f"state has {state.residual.size} residual-feature values but model "
                f"{self.name!r} needs {self.residual_state_size}: it was saved by a different model"
            )
        finite = (np.all(np.isfinite(a)) for a in (state.z, state.reference, state.residual))
        if not all(finite):
            raise ModelError("state contains NaN or inf")

    def referenced_to_start(self) -> CompiledModel:
        """This model with every input taken from its value at start (a record measured from its start)."""
        return replace(self, fixed_reference=np.full(self.n_submodels, np.nan), ambient_index=-1)

    def rest_state(self, signals: np.ndarray | Mapping[str, float]) -> ModelState:
        """All TF states zero; references as :mod:`compd.model.zero` finds them at ``signals``."""
        reference = self._references(signals)
        residual = self._residual_state(self._vector(signals))
        return ModelState(np.zeros((self.n_submodels, self.n_states)), reference, residual)

    def steady_state(self, signals: np.ndarray | Mapping[str, float]) -> ModelState:
        """The state in equilibrium with ``signals`` held constant: no start-up transient.

        For a DF2T filter fed a constant ``u`` the steady output is
        ``y = K u`` with ``K = B(1)/A(1)`` and ``z_i = sum_{k>i} (b_k u - a_k y)``.
        """
        vector = self._vector(signals)
        reference = self._references(vector)
        extended = self.extended(vector)
        u = self.raw_inputs(extended) - reference
        u = u * (self.gates_open(extended) | ~self.gate_on_input)
        y = u * self.b.sum(axis=1) / self.a.sum(axis=1)
        terms = self.b[:, 1:] * u[:, None] - self.a[:, 1:] * y[:, None]
        z = np.cumsum(terms[:, ::-1], axis=1)[:, ::-1]
        return ModelState(np.ascontiguousarray(z), reference, self._residual_state(vector))

    def _vector(self, signals: np.ndarray | Mapping[str, float]) -> np.ndarray:
        vector = (
            self.signal_vector(signals)
            if isinstance(signals, Mapping)
            else np.asarray(signals, float)
        )
        if vector.shape != (len(self.signals),) or not np.all(np.isfinite(vector)):
            raise ModelError(
                f"initial signals must be {len(self.signals)} finite values in the order "
                f"{list(self.signals)}, got {vector.tolist()}"
            )
        return vector

    def reads_cold(self, signals: np.ndarray | Mapping[str, float]) -> bool:
        """True when these readings start the model from them, as a cold machine (:mod:`compd.model.zero`)."""
        return start_references(self, self._vector(signals))[1]

    def _references(self, signals: np.ndarray | Mapping[str, float]) -> np.ndarray:
        return start_references(self, self._vector(signals))[0]


def compile_model(
    model: Model,
    sample_time_s: float | None = None,
    *,
    equations: tuple[DifferenceEquations, ...] = (),
    convert: bool = True,
) -> CompiledModel:
    """Compile ``model`` to run at ``sample_time_s`` (default: the model's own).

    ``equations`` are the difference equations its file carries
    (:mod:`compd.model.precompiled`): the set at ``sample_time_s`` is run as
    it is. Without one, a TF that needs converting (continuous, or discrete at
    another rate) is converted (scipy) when ``convert``, else refused with
    :class:`~compd.model.precompiled.ConversionNeeded`: the daemon compiles
    with ``convert=False`` and numpy alone.

    Raises :class:`ModelError` naming the sub-model (``outputs.X.submodels[i]``)
    when one is non-causal, unstable, cannot be brought to the sample time,
    or exceeds the bounds of :mod:`compd.model.limits` (checked before any
    state is allocated; the last check simulates each sub-model's step response).
    """
    run_s = float(model.sample_time_s if sample_time_s is None else sample_time_s)
    for what, value in (("the model's sample time", model.sample_time_s), ("sample time", run_s)):
        if not (np.isfinite(value) and 0 < value <= MAX_SAMPLE_TIME_S):
            raise ModelError(f"{what} must be > 0 and <= {MAX_SAMPLE_TIME_S:g} s, got {value}")
    if not model.outputs or not any(output.submodels for output in model.outputs):
        raise ModelError(f"model {model.name!r} has no sub-models")
    count = sum(len(output.submodels) for output in model.outputs)
    if count > MAX_SUBMODELS:
        raise ModelError(
            f"model {model.name!r} has {count} sub-models; compd runs up to {MAX_SUBMODELS}"
        )
    signals = model.signals()
    index = {name: i for i, name in enumerate(signals)}
    zero_slot, one_slot = len(signals), len(signals) + 1

    subs: list[SubModel] = []
    paths: list[str] = []
    tfs: list[DiscreteTF] = []
    owner: list[int] = []
    stored = stored_at(equations, run_s)
    for out_i, output in enumerate(model.outputs):
        for sub_i, sub in enumerate(output.submodels):
            path = f"outputs.{output.name}.submodels[{sub_i}] ({sub.name})"
            try:
                key = (output.name, sub.name)
                tf = runnable_tf(sub.tf, key, model.sample_time_s, run_s, stored, convert=convert)
                tfs.append(tf)
                _check_gain(tfs[-1], sub.gain)
            except ModelError as exc:
                raise type(exc)(exc.message, where=path) from exc
            subs.append(sub)
            paths.append(path)
            owner.append(out_i)

    length = max(max(tf.nk + len(tf.num), tf.order + 1) for tf in tfs)
    if len(tfs) * length > MAX_STATES:
        raise ModelError(
            f"model {model.name!r} would run {len(tfs)} sub-models x {length} states (the longest "
            f"delay line) = {len(tfs) * length}; compd runs up to {MAX_STATES}. Use shorter "
            "delays or fewer sub-models"
        )
    b = np.zeros((len(tfs), length))
    a = np.zeros((len(tfs), length))
    for row, tf in enumerate(tfs):
        b[row, : tf.b.size] = tf.b
        a[row, : tf.a.size] = tf.a
    output_matrix = np.zeros((len(model.outputs), len(tfs)))
    output_matrix[owner, np.arange(len(tfs))] = 1.0
    _check_step_responses(b, a, np.array([s.gain for s in subs], dtype=float), paths)

    return CompiledModel(
        name=model.name,
        sample_time_s=run_s,
        signals=signals,
        output_names=tuple(output.name for output in model.outputs),
        submodels=tuple(subs),
        submodel_paths=tuple(paths),
        discrete=tuple(tfs),
        b=b,
        a=a,
        plus_index=np.array([index[s.input.signal] for s in subs], dtype=np.intp),
        minus_index=np.array(
            [zero_slot if s.input.minus is None else index[s.input.minus] for s in subs],
            dtype=np.intp,
        ),
        fixed_reference=np.array(
            [np.nan if s.input.reference is None else s.input.reference for s in subs]
        ),
        gate_index=np.array(
            [one_slot if s.gate is None else index[s.gate.signal] for s in subs], dtype=np.intp
        ),
        gate_threshold=np.array([s.gate.threshold if s.gate else 0.0 for s in subs]),
        gate_sign=np.array([1.0 if s.gate is None or s.gate.above else -1.0 for s in subs]),
        gate_on_input=np.array(
            [s.gate is not None and s.gate.target is GateTarget.INPUT for s in subs]
        ),
        gain=np.array([s.gain for s in subs], dtype=float),
        position_index=np.array(
            [one_slot if s.position is None else index[s.position.signal] for s in subs],
            dtype=np.intp,
        ),
        position_reference_mm=np.array(
            [0.0 if s.position is None else s.position.reference_mm for s in subs], dtype=float
        ),
        output_matrix=output_matrix,
        ambient_index=-1 if model.ambient is None else index[model.ambient.signal],
        ambient_reference=0.0 if model.ambient is None else model.ambient.reference,
        ambient_moves=np.array(
            [model.ambient is not None and s.input.signal in model.ambient.moves for s in subs]
        ),
        residuals=tuple(
            (out_i, output.residual)
            for out_i, output in enumerate(model.outputs)
            if output.residual is not None
        ),
        output_bias_um=np.array([output.bias_um for output in model.outputs], dtype=float),
    )


def _check_gain(tf: DiscreteTF, gain: float) -> None:
    """Refuse a non-finite or absurd ``|gain * B(1)/A(1)|`` (um per input unit)."""
    with np.errstate(all="ignore"):
        total = gain * tf.static_gain()
    if not (np.isfinite(total) and abs(total) <= MAX_GAIN_UM_PER_UNIT):
        raise ModelError(
            f"static gain {total:.4g} um per input unit (gain {gain:.4g} x TF {tf.static_gain():.4g}) "
            f"is not within +-{MAX_GAIN_UM_PER_UNIT:g}: no thermal model moves an axis that far. "
            "Check the units and the coefficients"
        )


def _check_step_responses(b: np.ndarray, a: np.ndarray, gain: np.ndarray, paths: list[str]) -> None:
    """Simulate each sub-model's unit-step response for a while: finite and within the gain bound.

    The static gain bounds the end of the response; this bounds the way
    there (a stable but badly conditioned TF can overflow on its way).
    """
    step = np.ones(CHECK_SAMPLES)
    for row, path in enumerate(paths):
        with np.errstate(all="ignore"):
            response = lfilter(b[row], a[row], step)[0] * gain[row]
            peak = float(np.max(np.abs(response)))
        if not (np.isfinite(peak) and peak <= MAX_GAIN_UM_PER_UNIT):
            raise ModelError(
                f"its unit-step response reaches {peak:.4g} um within {CHECK_SAMPLES} samples "
                f"(bound +-{MAX_GAIN_UM_PER_UNIT:g}): the output would not stay finite. Check "
                "the coefficients",
                where=path,
            )


def qualified_names(compiled: CompiledModel) -> Sequence[str]:
    """``output/submodel`` names, one per sub-model row."""
    owners = compiled.output_matrix.argmax(axis=0)
    return [
        f"{compiled.output_names[o]}/{s.name}"
        for o, s in zip(owners, compiled.submodels, strict=True)
    ]
