"""Model slots: a loaded model (file, compiled form, runner), and the slots the loop switches between.

A :class:`ModelSlot` is one model file, compiled, and once started its
runner; it knows which signals each of its outputs depends on, so that an
axis freezes only for a fault of an input it uses. :class:`ModelSlots` holds
up to four at once -- the active model, the one it blends out of, the one
waiting to be switched in, and the one to restore should the active one
fail -- and steps, switches, blends and unloads them, tick by tick, for the
compensator (:mod:`compd.service.loop.compensator`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np
import structlog

from compd.faultlog import Event, EventSink
from compd.files.modelfile import ModelFile
from compd.model.compiled import CompiledModel, ModelState, qualified_names
from compd.model.handover import SignalHistory, handover_state
from compd.model.run import TickRunner
from compd.model.zero import COLD_BAND_DEGC
from compd.service.loop.schedule import GainScheduler

if TYPE_CHECKING:
    from compd.service.loop.compensator import Counters

log = structlog.get_logger("compd.service.loop.slots")


class ModelSlot:
    """A loaded model: its file, compiled form, and once started, its runner."""

    def __init__(self, model_file: ModelFile, compiled: CompiledModel, loaded_at_unix_s: float):
        self.model_file = model_file
        self.compiled = compiled
        self.loaded_at_unix_s = loaded_at_unix_s
        self.runner: TickRunner | None = None
        #: How the running model's state was set at its start (said in the log and the status).
        self.initialised: str | None = None
        #: Started from today's readings as a cold machine's (or as the zero): what the probes
        #: learned as a constant does not carry over (:meth:`OutputLearner.forget_shift`).
        self.started_cold = False
        #: The outputs (um) of the last tick, in ``compiled.output_names`` order (NaN: none).
        self.outputs: list[float] = [math.nan] * len(compiled.output_names)
        self.names = list(qualified_names(compiled))
        self._index = {name: i for i, name in enumerate(compiled.output_names)}
        owners = compiled.output_matrix.argmax(axis=0)
        #: Signals each output depends on (inputs, minus signals, gates and positions of its sub-models).
        self.depends: dict[str, set[str]] = {name: set() for name in compiled.output_names}
        for owner, sub in zip(owners, compiled.submodels, strict=True):
            self.depends[compiled.output_names[owner]] |= set(sub.signals())
        for owner, residual in compiled.residuals:  # a door residual reads its signal too
            self.depends[compiled.output_names[owner]].add(residual.signal)

    @property
    def sha256(self) -> str:
        return self.model_file.sha256

    def start(self, state: ModelState, how: str | None = None) -> None:
        """Run from ``state``; ``how`` (how it was found) is logged and kept for the status."""
        self.runner = TickRunner(self.compiled, state)
        if how is not None:
            self.initialised = how
            log.info("initial state", model=self.compiled.name, how=how)

    def start_steady(self, checked: Mapping[str, float], *, zero_now: bool = False) -> None:
        """Start at the steady state for the current inputs (no saved state, no history).

        ``zero_now``: from rest with today's readings as the zero instead
        (``state.fresh_start: now``), so the offsets start from 0.
        """
        self.start(*fresh_state(self.compiled, checked, zero_now=zero_now))
        self.started_cold = zero_now or self.compiled.reads_cold(checked)

    def output(self, name: str) -> float:
        return self.outputs[self._index[name]]


#: What a start from today's readings (``state.fresh_start: now``) means, for the log and status.
ZERO_NOW_NOTE = (
    "today's readings taken as the zero (state.fresh_start: now): offsets from 0, drift before "
    "the start left to the work offset (touched off on the warm machine)"
)


def fresh_state(
    compiled: CompiledModel, checked: Mapping[str, float], *, zero_now: bool = False
) -> tuple[ModelState, str]:
    """The state a model starts from without a saved state or history, and how it was found."""
    if zero_now:
        return compiled.referenced_to_start().rest_state(checked), ZERO_NOW_NOTE
    cold = compiled.reads_cold(checked)
    return compiled.steady_state(checked), steady_note(compiled, cold)


def steady_note(compiled: CompiledModel, cold: bool = False) -> str:
    """What a start at the steady state for the current inputs means for this model's references."""
    total = compiled.n_submodels
    at_start = int(np.sum(np.isnan(compiled.fixed_reference)))
    if cold:
        return (
            f"the machine reads cold (every temperature within {COLD_BAND_DEGC:g} degC of the "
            "model's thermal zero): today's readings taken as its zero, offsets from 0"
        )
    if at_start == 0:
        air = (
            ""
            if compiled.ambient_index < 0
            else f" (moved with {compiled.signals[compiled.ambient_index]})"
        )
        return (
            f"steady state for the current inputs, from the model's thermal zero{air} (absolute "
            "references): drift before the start is compensated, ramped in at the slew limit"
        )
    which = "every input" if at_start == total else f"{at_start} of {total} sub-models' inputs"
    return (
        f"steady state for the current inputs; {which} taken from its value now (reference: "
        "start): drift before the start is not compensated. Refit (compd fit writes absolute "
        "references) or resume a saved state"
    )


class ModelSlots:
    """The models the loop runs: the active one, the one it blends out of, the pending one, the fallback.

    Each tick (:meth:`step`) a pending model whose inputs are complete is
    switched in: started warm from the recent inputs (:mod:`compd.model.handover`)
    while another runs, and then both run and blend ``w * new + (1 - w) * old``
    with ``w`` rising 0 -> 1 over ``blend_s`` (:meth:`blend_weight`). A model
    that raises or whose state turns NaN/inf is unloaded and the one it
    replaced restored (``on_failure`` is told, so the service can un-install
    it); a non-finite output is a model fault (:attr:`fault`), logged once.
    """

    def __init__(
        self,
        active: ModelSlot,
        signals: Sequence[str],
        counters: Counters,
        *,
        blend_s: float = 60.0,
        history_ticks: int = 28_800,
        schedule: GainScheduler | None = None,
        on_failure: Callable[[ModelSlot, ModelSlot], None] | None = None,
        zero_now: bool = False,
    ) -> None:
        self.active = active
        #: ``state.fresh_start: now``: a model started without state or history starts from 0.
        self.zero_now = zero_now
        self.previous: ModelSlot | None = None
        self.pending: ModelSlot | None = None
        #: The model to restore if the active one fails (the one it replaced).
        self.fallback: ModelSlot | None = None
        #: Why the model is faulted (None while its outputs are finite): logged once, the model-fault bit.
        self.fault: str | None = None
        self.blend_s = blend_s
        self.blend_start_s = -math.inf
        #: Gains by operating condition (:mod:`compd.service.loop.schedule`), applied before each step.
        self.schedule = schedule
        self.on_failure = on_failure
        #: The tick's counters: model loads and failures are counted here.
        self.counters = counters
        #: The inputs of the last ``history_ticks`` ticks, to start a newly loaded model warm.
        self.history = SignalHistory(list(signals), history_ticks)
        #: Told of model switches, failures and faults (the telemetry), where attached.
        self.events: EventSink | None = None

    def _tell(self, kind: str, message: str, **details: object) -> None:
        if self.events is not None:
            self.events(Event(kind, message, details))

    def load(self, slot: ModelSlot) -> None:
        """Switch to ``slot`` at the next tick whose inputs are complete, blending bumplessly."""
        self.pending = slot

    def blend_weight(self, t_s: float) -> float | None:
        """``w`` of the blend at ``t_s`` while one runs, else None (and the outgoing model is let go)."""
        weight = min(1.0, (t_s - self.blend_start_s) / self.blend_s) if self.blend_s else 1.0
        if weight >= 1.0 and self.previous is not None:
            self.previous = None
            blended = {"model": self.active.compiled.name, "sha256": self.active.sha256}
            log.info("model blended in", **blended, blend_s=self.blend_s)  # the journal too
            self._tell("model_blended", "model blended in", **blended, blend_s=self.blend_s)
        return None if self.previous is None else weight

    def output(self, name: str, weight: float | None) -> float:
        """The output ``name``: the active model's, blended with the outgoing one's at ``weight``."""
        output = self.active.output(name)
        if weight is not None and self.previous is not None:
            output = weight * output + (1 - weight) * self.previous.output(name)
        return output

    def step(self, t_s: float, checked: Mapping[str, float]) -> None:
        """Switch in a pending model whose inputs are complete, then step the active and the outgoing one."""
        self.history.append(checked)
        pending = self.pending
        fault: str | None = None
        if pending is not None and self._complete(pending, checked):
            self.pending = None
            try:
                pending.start(*self._handover(pending, checked))
            except Exception as exc:  # any failure of a new model: refuse it, keep the running one
                fault = self._failed(pending, self.active, f"could not start: {exc!r}")
            else:
                if self.active.runner is not None:
                    self.previous, self.blend_start_s = self.active, t_s
                self.fallback, self.active = self.active, pending
                self.counters.model_loads += 1
                switched = {"model": pending.compiled.name, "sha256": pending.sha256}
                blending = self.previous is not None
                log.info("model switched in", **switched, blending=blending)  # the journal too
                self._tell("model_switched", "model switched in", **switched, blending=blending)
        for slot in (self.active, self.previous):
            if slot is None:
                continue
            if not self._complete(slot, checked):
                slot.outputs = [math.nan] * len(slot.outputs)
                continue
            try:
                if slot.runner is None:
                    slot.start_steady(checked, zero_now=self.zero_now)
                assert slot.runner is not None
                if self.schedule is not None:
                    self.schedule.apply(slot.runner)
                slot.outputs = slot.runner.step(checked)
            except Exception as exc:  # a model must never end the loop
                slot.outputs = [math.nan] * len(slot.outputs)
                fault = self._unload(slot, f"failed: {exc!r}")
                continue
            if not all(map(math.isfinite, slot.outputs)):
                fault = f"model {slot.compiled.name!r} gave a non-finite output"
                state = slot.runner.state
                if not all(np.all(np.isfinite(v)) for v in (state.z, state.residual)):
                    fault = self._unload(slot, "its state turned NaN/inf")
        if fault is not None or self.fault is not None:  # (nothing to latch otherwise)
            self._latch_fault(fault)

    def _unload(self, slot: ModelSlot, why: str) -> str:
        """Take a failed model out of the loop: restore the one it replaced, or restart it."""
        slot.runner = None
        if slot is self.previous:  # the outgoing model of a blend: the blend ends early
            self.previous = None
            return f"model {slot.compiled.name!r} (blending out) {why}"
        restore = self.fallback
        if restore is None or restore is slot:
            return f"model {slot.compiled.name!r} {why}; restarting it from its inputs"
        if restore is not self.previous:
            history = self.history.matrix(restore.compiled.signals)
            restore.runner = None
            restore.outputs = [math.nan] * len(restore.outputs)  # not stepped: the axes hold
            if len(history) >= 2:  # warm, from the recent inputs (compd.model.handover)
                try:
                    restore.start(
                        handover_state(restore.compiled, history),
                        f"from the last {len(history)} ticks of inputs (restored)",
                    )
                except Exception:  # then from steady state with the next inputs
                    log.warning("restored model starts cold", model=restore.compiled.name)
        self.active, self.previous, self.fallback = restore, None, None
        return self._failed(slot, restore, why)

    def _failed(self, failed: ModelSlot, restored: ModelSlot, why: str) -> str:
        self.counters.model_failures += 1
        log.error(
            "model failed and was unloaded",
            model=failed.compiled.name,
            sha256=failed.sha256,
            reason=why,
            restored=restored.compiled.name,
        )
        message = f"model {failed.compiled.name!r} {why}; restored {restored.compiled.name!r}"
        self._tell(
            "model_failed", "model failed and was unloaded", model=failed.compiled.name,
            sha256=failed.sha256, reason=why, restored=restored.compiled.name,
        )  # fmt: skip
        self.fault = message  # logged here: the latch only follows it (DEBUG, then INFO)
        if self.on_failure is not None:
            self.on_failure(failed, restored)
        return message

    def _latch_fault(self, fault: str | None) -> None:
        """ERROR once when a model fault starts, DEBUG while it lasts, INFO when it ends."""
        if fault is not None and self.fault is None:
            log.error("model fault: the axes hold their offsets", reason=fault)
            self._tell("fault", "model fault: the axes hold their offsets", reason=fault)
        elif fault is not None:
            log.debug("model fault goes on", reason=fault)
        elif self.fault is not None and all(map(math.isfinite, self.active.outputs)):
            log.info("model outputs are finite again", model=self.active.compiled.name)
            self._tell("cleared", "model outputs are finite again", model=self.active.compiled.name)
        else:
            return
        self.fault = fault

    def _handover(self, pending: ModelSlot, checked: Mapping[str, float]) -> tuple[ModelState, str]:
        """A model switched in while another runs starts warm (:mod:`compd.model.handover`)."""
        running = self.active
        history = self.history.matrix(pending.compiled.signals)
        if running.runner is None or len(history) < 2:
            return fresh_state(pending.compiled, checked, zero_now=self.zero_now)
        state = handover_state(pending.compiled, history, running.compiled, running.runner.state)
        return state, f"from the last {len(history)} ticks of inputs, shared sub-models handed over"

    @staticmethod
    def _complete(slot: ModelSlot, checked: Mapping[str, float]) -> bool:
        return all(map(math.isfinite, map(checked.__getitem__, slot.compiled.signals)))
