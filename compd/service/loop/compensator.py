"""The per-tick function: read, check, step the model, limit, write, in that order.

:class:`Compensator` is what the scheduler (:mod:`compd.service.loop.ticks`) calls
once per period. Every I/O goes through the per-driver batches of
:mod:`compd.service.loop.points` (each a :class:`~compd.service.loop.links.DriverLink`),
so that no I/O error can end the loop; the models it steps are the slots of
:mod:`compd.service.loop.slots`.
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import structlog

from compd.errors import CompdError
from compd.faultlog import Event, EventSink, FaultLog
from compd.model.compiled import ModelState
from compd.model.consistency import ConsistencyCheck
from compd.service.loop.envelope import EnvelopeFaults
from compd.service.loop.links import DriverLink
from compd.service.loop.offsets import AxisPoint, HeldOffsets
from compd.service.loop.plausibility import DEFAULT_SETTINGS, Plausibility, PlausibilitySettings
from compd.service.loop.points import DriverBatches, SignalPoint, StatusPoint
from compd.service.loop.probemessages import ProbeTaken
from compd.service.loop.redundancy import Pair, Redundancy
from compd.service.loop.safety import HEARTBEAT_MODULO, AxisSafety, Flag, Level, status_word
from compd.service.loop.schedule import GainScheduler
from compd.service.loop.signals import Health, Reading, SignalMonitor
from compd.service.loop.slots import ModelSlot, ModelSlots

if TYPE_CHECKING:
    from compd.service.loop.probing import ProbeLearning

log = structlog.get_logger("compd.service.loop.compensator")

#: The smallest rate limit (per tick, in the signal's unit) a calibration sets for an input
#: whose config names none: 3x the fastest move it saw, but never below this.
MIN_DEFAULT_JUMP = 1.0


@dataclass(slots=True)
class TickRecord:
    """Everything one tick saw and did, for the recorder, the status and the tests."""

    t_s: float
    wall_unix_s: float
    #: The value each input had for the model this tick (held, or estimated from the others).
    values: dict[str, float]
    health: dict[str, Health]
    reasons: dict[str, str]
    model_outputs: dict[str, float]
    contributions: dict[str, float]
    targets_um: dict[str, float]
    offsets_um: dict[str, float]
    status: int
    heartbeat: int
    written: bool
    #: The scheduled gains in use (gain_name -> value); empty without a gain schedule.
    gains: dict[str, float] = field(default_factory=dict)
    #: Per axis, the offset the device acknowledged this tick (NaN: not written this tick).
    acknowledged_um: dict[str, float] = field(default_factory=dict)
    #: Per axis with readback, the offset the device held at the start of the tick (NaN: unknown).
    readback_um: dict[str, float] = field(default_factory=dict)
    #: What each input read this tick, scaled (NaN: no new value); ``values`` is what was used.
    read: dict[str, float] = field(default_factory=dict)
    #: The probes taken this tick (:mod:`compd.service.loop.probing`), and per output what the
    #: probes so far add to the model's output (um).
    probes: tuple[ProbeTaken, ...] = ()
    probe_adjustments_um: dict[str, float] = field(default_factory=dict)
    #: Per probed axis, the innovation of a probe taken this tick (um; NaN: none this tick).
    probe_innovations_um: dict[str, float] = field(default_factory=dict)
    #: Per axis whose target is outside its envelope, what and for how long
    #: (``Z at the clamp +150 um (target +163.2 um) for 4 min``; :mod:`compd.service.loop.envelope`).
    outside_envelope: dict[str, str] = field(default_factory=dict)


@dataclass
class Counters:
    ticks: int = 0
    signal_faults: int = 0
    write_failures: int = 0
    model_loads: int = 0
    #: Offsets read back (per axis and tick) that were not what compd last wrote.
    offset_mismatches: int = 0
    #: Models that failed while running (an exception, a state gone NaN/inf) and were unloaded.
    model_failures: int = 0
    #: Offsets read back (per axis and tick) outside the clamp or not finite, replaced not followed.
    offsets_out_of_clamp: int = 0
    #: Episodes of an input replaced by its prediction from the other sensors.
    signal_estimates: int = 0
    #: Episodes of an axis's target outside its envelope for ``envelope_after_s``.
    envelope_faults: int = 0
    #: Episodes of a redundant pair: the two disagreed, or one failed its own checks.
    redundancy_faults: int = 0


class Compensator:
    """The per-tick function: read, check, step the model, limit, write; no I/O error escapes.

    One tick at time ``t_s``:

    1. read every signal, all drivers concurrently, each under its timeout;
    2. check each value (:class:`~compd.service.loop.signals.SignalMonitor`): good, held, or faulted;
    3. step the model with the checked values (started at steady state with the first
       complete set of values, or from a resumed state), switching in a loaded model
       bumplessly and unloading a failed one (:class:`~compd.service.loop.slots.ModelSlots`;
       ``on_model_failure`` is told); a model fault sets the model-fault bit and level
       faulted;
    4. per axis ``target = sign * output``, through the safety stage, frozen while an
       input the axis depends on is faulted; an axis whose offset read back outside its
       clamp (or not finite) writes its stage's recovery value instead (level faulted
       and the mismatch bit, :mod:`compd.service.loop.safety`); an axis whose target has
       been at the clamp or beyond its model's calibration for minutes is faulted too
       (:mod:`compd.service.loop.envelope`: level faulted, the model-fault bit);
    5. write offsets, status word and heartbeat, all drivers concurrently.

    Without a model (``model=None``: a data logger, no axes) steps 3 and 4 are
    skipped: the signals are read and checked for the recorder, and only a
    status word and heartbeat are written, where the config has them.

    The stage slews from what each device holds (:class:`~compd.service.loop.offsets.HeldOffsets`):
    the offset read back at step 1 where the driver can, else the last acknowledged write.
    """

    def __init__(
        self,
        *,
        signals: Sequence[SignalPoint],
        monitors: Mapping[str, SignalMonitor],
        axes: Sequence[AxisPoint],
        safety: Mapping[str, AxisSafety],
        links: Mapping[str, DriverLink],
        model: ModelSlot | None,
        status: StatusPoint | None = None,
        blend_s: float = 60.0,
        wall_at: Callable[[float], float] = lambda t_s: time.time(),
        initial_state: ModelState | None = None,
        schedule: GainScheduler | None = None,
        history_ticks: int = 28_800,
        on_model_failure: Callable[[ModelSlot, ModelSlot], None] | None = None,
        zero_now: bool = False,
        period_s: float = 1.0,
        plausibility: PlausibilitySettings | None = DEFAULT_SETTINGS,
        units: Mapping[str, str] | None = None,
        probing: ProbeLearning | None = None,
        pairs: Sequence[Pair] = (),
    ) -> None:
        self.signals = list(signals)
        self._signal_names = [point.name for point in self.signals]
        self.monitors = dict(monitors)
        self.axes = list(axes)
        self._axis_names = [axis.name for axis in self.axes]
        self._readback_axes = [axis for axis in self.axes if axis.readback]
        self.safety = dict(safety)
        self.links = dict(links)
        self.status_point = status
        self.wall_at = wall_at
        #: Gains by operating condition (:mod:`compd.service.loop.schedule`), applied before each step.
        self.schedule = schedule
        self.heartbeat = 0
        self.counters = Counters()
        self.last: TickRecord | None = None
        if model is None and self.axes:
            raise ValueError("axes need a model to compute their offsets")
        #: The models run, switched, blended and unloaded (:mod:`compd.service.loop.slots`); None: a logger.
        self.models = (
            ModelSlots(
                model,
                [p.name for p in self.signals],
                self.counters,
                blend_s=blend_s,
                history_ticks=history_ticks,
                schedule=schedule,
                on_failure=on_model_failure,
                zero_now=zero_now,
            )
            if model is not None
            else None
        )
        #: The signals, offsets and status word, batched per driver (:mod:`compd.service.loop.points`).
        #: Probe measurements updating the running model (:mod:`compd.service.loop.probing`); None: off.
        self.probing = probing if model is not None else None
        also_read = [] if self.probing is None else self.probing.reads()
        self.points = DriverBatches(self.signals, self.axes, status, self.links, also_read)
        if initial_state is not None and model is not None:
            model.start(initial_state, "resumed from the saved state")
        #: What each offset point holds, as far as compd knows (:mod:`compd.service.loop.offsets`).
        self.held = HeldOffsets(self.axes, self.safety)
        #: Told of signal faults and model events (the telemetry), where attached.
        self.events: EventSink | None = None
        #: Signals whose fault was told and not yet its end: ``cleared`` only ever follows a ``fault``
        #: (every signal starts faulted, "no value yet", and its first good value is no recovery).
        self._told_faulted: set[str] = set()
        #: One ERROR line at the start of each signal's fault episode, one INFO line at its end.
        self._signal_faults = {p.name: FaultLog(log, signal=p.name) for p in self.signals}
        self.period_s = period_s
        self.units = dict(units or {})
        self.plausibility_settings = plausibility
        #: The inputs checked against each other (:mod:`compd.service.loop.plausibility`), from the
        #: running model's consistency model; None without one (older model files, a logger).
        self.plausibility: Plausibility | None = None
        self._plausibility_of: str | None = None
        self._estimates_seen = 0
        self._configured_jumps = {name: m.checks.max_jump for name, m in self.monitors.items()}
        #: Each axis's envelope-fault episodes, and the model whose envelopes the stages hold.
        self.envelope_faults = EnvelopeFaults(a.name for a in self.axes)
        self._envelope_of: str | None = None
        #: Model inputs with a second sensor of the same point (:mod:`compd.service.loop.redundancy`).
        self.redundancy = Redundancy(list(pairs), self.monitors, period_s) if pairs else None

    # The model slots as the status and the tests see them (:class:`ModelSlots`).
    @property
    def active(self) -> ModelSlot:
        """The model whose outputs the axes follow; a logger has none (check :attr:`models`)."""
        if self.models is None:
            raise AttributeError("a data logger runs no model")
        return self.models.active

    @property
    def running(self) -> ModelSlot | None:
        """The active model, or None for a data logger."""
        return None if self.models is None else self.models.active

    @property
    def previous(self) -> ModelSlot | None:
        """The model being blended out, if a blend runs."""
        return None if self.models is None else self.models.previous

    @property
    def pending(self) -> ModelSlot | None:
        """The model loaded but not yet switched in."""
        return None if self.models is None else self.models.pending

    @property
    def model_fault(self) -> str | None:
        """Why the model is faulted; None while its outputs are finite."""
        return None if self.models is None else self.models.fault

    def load(self, slot: ModelSlot) -> None:
        """Switch to ``slot`` at the next tick whose inputs are complete, blending bumplessly."""
        if self.models is None:
            raise ValueError("a data logger runs no model")
        self.models.load(slot)

    def report_to(self, sink: EventSink) -> None:
        """Tell ``sink`` of signal faults and the models' switches, failures and faults."""
        self.events = sink
        if self.models is not None:  # a data logger has none
            self.models.events = sink
        if self.plausibility is not None:
            self.plausibility.report_to(sink)
        self.envelope_faults.report_to(sink)
        if self.redundancy is not None:
            self.redundancy.report_to(sink)

    def trust_signal(self, name: str) -> str:
        """A person vouches for ``name``'s sensor (``compd sensor trust``): its stand-in ends at
        its next good reading."""
        if name not in self.monitors:
            known = ", ".join(sorted(self.monitors))
            raise CompdError(f"there is no signal {name!r}; the config's signals: {known}")
        if self.plausibility is None:
            return f"{name}: no consistency check runs, so nothing stands in for it"
        return self.plausibility.trust(name)

    def _redundant(self, t_s: float, readings: dict[str, Reading]) -> dict[str, Reading]:
        """Each redundant pair's primary as the pair says (before the inputs are checked against
        each other); its prediction from the other sensors is the last tick's."""
        redundancy = self.redundancy
        if redundancy is None:
            return readings
        judged = self.plausibility
        predicted: dict[str, float | None] = {}
        if judged is not None:
            for check in redundancy.checks:
                p = judged.predictions.get(check.pair.primary)
                predicted[check.pair.primary] = None if p is None else p.value
        out = redundancy.apply(t_s, readings, predicted)
        self.counters.redundancy_faults = redundancy.count
        return out

    def _plausible(
        self, t_s: float, readings: dict[str, Reading], read: Mapping[str, float | None]
    ) -> dict[str, Reading]:
        """The readings after the inputs were checked against each other (unchanged without a check)."""
        slot = self.running
        if slot is None or self.plausibility_settings is None:
            return readings
        if self._plausibility_of != slot.sha256:
            self._plausibility_of = slot.sha256
            self.plausibility = self._plausibility_for(slot)
        if self.plausibility is None:
            return readings
        vouched = set() if self.redundancy is None else self.redundancy.vouched()
        out = self.plausibility.judge(t_s, readings, read, verified=vouched)
        self.counters.signal_estimates += self.plausibility.count - self._estimates_seen
        self._estimates_seen = self.plausibility.count
        return out

    def _plausibility_for(self, slot: ModelSlot) -> Plausibility | None:
        """The check of ``slot``'s inputs against each other; each input's rate limit defaults to its calibration's."""
        model = slot.model_file.consistency()
        for name, monitor in self.monitors.items():  # a new model: its own defaults
            monitor.checks = replace(monitor.checks, max_jump=self._configured_jumps[name])
        if model is None:
            log.warning(
                "no consistency check in this file: inputs are checked one by one",
                model=slot.compiled.name,
            )
            return None
        assert self.plausibility_settings is not None
        settings = self.plausibility_settings
        for name, rate in zip(model.checked, model.max_rate_per_s, strict=True):
            checked = self.monitors.get(name)
            if checked is not None and checked.checks.max_jump is None:
                jump = max(3.0 * rate * self.period_s, MIN_DEFAULT_JUMP)
                checked.checks = replace(checked.checks, max_jump=jump)
        check = ConsistencyCheck(model, self.period_s, frozenset(self.monitors))
        plausibility = Plausibility(check, self.monitors, self.units, self.period_s, settings)
        if self.events is not None:
            plausibility.report_to(self.events)
        self._estimates_seen = 0
        return plausibility

    def _calibrate(self, slot: ModelSlot) -> None:
        """Each axis's envelope from ``slot``'s calibrated output range, when the running model changes."""
        if self._envelope_of == slot.sha256:
            return
        self._envelope_of = slot.sha256
        for axis in self.axes:
            output_range = slot.model_file.output_range(axis.model_output)
            self.safety[axis.name].calibrate(axis.sign, output_range)

    def _learn(self, probing: ProbeLearning, now_unix_s: float, slot: ModelSlot) -> None:
        """Feed the probe learning this tick; a failure in it turns probing off, never the loop."""
        try:
            probing.observe(now_unix_s, slot)
        except Exception as exc:
            log.exception("probe learning failed: probes are off until the daemon restarts")
            self._tell("fault", "probe learning failed", error=f"{type(exc).__name__}: {exc}")
            probing.turn_off(f"{type(exc).__name__}: {exc}")
        for taken in probing.taken():
            self._tell("probe", f"probe {taken.result}", **taken.event_details())

    def _tell(self, kind: str, message: str, **details: object) -> None:
        if self.events is not None:
            self.events(Event(kind, message, details))

    async def tick(self, t_s: float) -> TickRecord:
        values, held = await self.points.read()
        now_unix_s = self.wall_at(t_s)
        probing = self.probing
        if probing is not None:
            probing.read_registers(values, now_unix_s)
        mismatches = self.held.read_back(held)
        self.counters.offset_mismatches += mismatches
        out_of_clamp = self.held.out_of_clamp
        self.counters.offsets_out_of_clamp += len(out_of_clamp)
        readings = {}
        was = {}
        for point in self.signals:  # each monitor is its own: its health before, then its update
            monitor = self.monitors[point.name]
            was[point.name] = monitor.reading.health
            readings[point.name] = monitor.update(t_s, values.get(point.name))
        if self.redundancy is not None:
            readings = self._redundant(t_s, readings)
        readings = self._plausible(t_s, readings, values)
        if self.redundancy is not None:
            readings = self.redundancy.mark(readings)
        for point in self.signals:
            reading = readings[point.name]
            if reading.health is Health.FAULTED and was[point.name] is not Health.FAULTED:
                self.counters.signal_faults += 1
                self._told_faulted.add(point.name)
                self._tell("fault", "signal faulted", signal=point.name, reason=reading.reason)
                link = self.links.get(point.driver)
                if reading.reason != "no value yet" and (link is None or link.up):
                    read = values.get(point.name)
                    self._signal_faults[point.name].failed(
                        "signal faulted: the axes that depend on it freeze",
                        reason=reading.reason,
                        read=read,
                        held=reading.value,
                    )
            elif reading.health is not Health.FAULTED and point.name in self._told_faulted:
                self._told_faulted.discard(point.name)
                self._tell("cleared", "signal usable again", signal=point.name)
                self._signal_faults[point.name].cleared(
                    "signal usable again", health=reading.health.name.lower()
                )
        # The readings as the rest of the tick uses them, in one pass (the tick runs with cold
        # caches: each comprehension is a function and a frame of its own).
        checked: dict[str, float] = {}
        health: dict[str, Health] = {}
        reasons: dict[str, str] = {}
        faulted_now: set[str] = set()
        bad: list[bool] = []  # per input, in order: not OK (a status bit each)
        for name, reading in readings.items():
            checked[name] = reading.value
            health[name] = state = reading.health
            if reading.reason:
                reasons[name] = reading.reason
            if state is Health.FAULTED:
                faulted_now.add(name)
            bad.append(state is not Health.OK)
        if self.schedule is not None:
            key = readings[self.schedule.table.signal]
            self.schedule.update(t_s, key.value, usable=key.health is not Health.FAULTED)
        models = self.models
        weight = None
        if models is not None:
            models.step(t_s, checked)
            weight = models.blend_weight(t_s)
            if probing is not None:
                self._learn(probing, now_unix_s, models.active)
        targets: dict[str, float] = {}
        offsets: dict[str, float] = {}
        flags: set[Flag] = set()
        any_frozen = outside = False
        outside_envelope: dict[str, str] = {}
        if models is not None and self.axes:
            self._calibrate(models.active)
        for axis in self.axes:
            assert models is not None  # axes need a model (checked in __init__)
            output = models.output(axis.model_output, weight)
            learned = 0.0
            if probing is not None:  # what the probes taught; clamp and slew still apply
                learned = probing.adjustment(axis.model_output)
                output += learned
            if weight is not None:
                flags.add(Flag.BLENDING)
            faulted = not faulted_now.isdisjoint(models.active.depends[axis.model_output])
            targets[axis.name] = target = axis.sign * output
            stage = self.safety[axis.name]
            # An offset read back outside the clamp: this tick writes the policy's value as is.
            clamp_fault = axis.name in out_of_clamp
            result = (
                stage.hold()
                if clamp_fault
                else stage.step(target, t_s, faulted=faulted, measured_um=axis.sign * learned)
            )
            offsets[axis.name] = result.offset_um
            watch = stage.watch
            any_frozen |= faulted or clamp_fault or watch.faulted
            outside |= watch.faulted
            self.envelope_faults.update(axis.name, watch)
            if watch.why is not None and (said := watch.sentence(axis.name)) is not None:
                outside_envelope[axis.name] = said  # outside its envelope: how, and how long
            if result.clamped:
                flags.add(Flag.CLAMPED)
            if result.slewed:
                flags.add(Flag.SLEWING)
        if models is not None and models.active.runner is None:
            flags.add(Flag.STARTING)
        model_fault = None if models is None else models.fault
        if model_fault is not None:
            any_frozen = True
        # A link down, or a device refusing writes: the offsets are not getting through.
        for link in self.links.values():
            if not link.up or link.refusing_writes:
                flags.add(Flag.DRIVER_DOWN)
                break
        level = Level.FAULTED if any_frozen else Level.DEGRADED if any(bad) else Level.OK
        unsure = Flag.DRIVER_DOWN in flags or mismatches or self.held.unknown
        if unsure and level is Level.OK:
            level = Level.DEGRADED
        status = self.status_point
        word = status_word(
            level,
            flags,
            bad,
            mismatch=bool(mismatches or out_of_clamp)
            and status is not None
            and status.mismatch_bit,
            model_fault=(model_fault is not None or outside)
            and status is not None
            and status.model_fault_bit,
        )
        self.heartbeat = (self.heartbeat + 1) % HEARTBEAT_MODULO
        also = None if probing is None else probing.writes(now_unix_s)
        ok, acknowledged = await self._write(offsets, word, also)
        if probing is not None:
            probing.record_offsets(now_unix_s, self.held.known_um())
        written = ok and len(acknowledged) == len(self.axes)
        self.counters.ticks += 1
        self.counters.envelope_faults = self.envelope_faults.episodes
        outputs, contributions = _model_outputs(None if models is None else models.active)
        self.last = TickRecord(
            t_s=t_s,
            wall_unix_s=now_unix_s,
            values=checked,
            health=health,
            reasons=reasons,
            model_outputs=outputs,
            contributions=contributions,
            targets_um=targets,
            offsets_um=offsets,
            status=word,
            heartbeat=self.heartbeat,
            written=written,
            gains=dict(self.schedule.applied) if self.schedule is not None else {},
            acknowledged_um=_each(acknowledged, self._axis_names),
            readback_um={a.name: _um(a, held.get(a.name)) for a in self._readback_axes}
            if self._readback_axes
            else {},
            read=_each(values, self._signal_names),  # the points' values are floats already
            probes=() if probing is None else probing.taken(),
            probe_adjustments_um={} if probing is None else dict(probing.adjustments_um),
            probe_innovations_um={} if probing is None else probing.innovations_um(),
            outside_envelope=outside_envelope,
        )
        return self.last

    async def write_stopped(self) -> bool:
        """The last status word at shutdown (``STOPPED``), for the PLC; offsets are left as they are.

        Nothing at all before the first tick: a start that failed knows nothing
        the machine should be told, least of all an offset.
        """
        if self.last is None or self.status_point is None:
            return False
        word = status_word(Level(self.last.status & 0b11), [Flag.STOPPED], [])
        return await self.points.write_status(word, self.heartbeat)

    async def _write(
        self,
        offsets: Mapping[str, float],
        word: int,
        also: Mapping[str, Mapping[str, float]] | None = None,
    ) -> tuple[bool, dict[str, float]]:
        """Write what is safe to write; whether every write succeeded, and the offsets (um) acknowledged."""
        raws = self.held.to_write(offsets)
        ok = await self.points.write(raws, word, self.heartbeat, also)
        if not all(ok.values()):
            self.counters.write_failures += 1
        return all(ok.values()), self.held.written(raws, ok)


def _model_outputs(slot: ModelSlot | None) -> tuple[dict[str, float], dict[str, float]]:
    """The active model's outputs and each sub-model's contribution (NaN before it starts)."""
    if slot is None:
        return {}, {}
    outputs = dict(zip(slot.compiled.output_names, slot.outputs, strict=True))
    runner = slot.runner
    if runner is None:
        return outputs, {name: math.nan for name in slot.names}
    return outputs, dict(zip(slot.names, runner.contributions_um, strict=True))


#: NaN as often as asked: the default of ``map(mapping.get, names, _NAN)``.
_NAN = itertools.repeat(math.nan)


def _each(values: Mapping[str, float], names: list[str]) -> dict[str, float]:
    """``values`` of ``names``, in their order, NaN where missing (in C: no frame per tick)."""
    return dict(zip(names, map(values.get, names, _NAN), strict=True))


def _um(axis: AxisPoint, raw: float | None) -> float:
    return math.nan if raw is None else axis.decode(raw)
