"""The offset safety stage: the last thing between the model and the machine, per axis.

After LinuxCNC's ``limit2`` (clamp, then slew-limit against the last output,
with a ``load`` to re-seed), SINUMERIK's rate limit on temperature
compensation and Heidenhain's 1 um/s follow-up. Each tick, for an axis with
limits ``M = max_offset_um`` and ``R = max_rate_um_per_s`` at period ``T``::

    target  = last                   if the target is NaN/inf, an input is faulted, or the
                                     target has been outside its envelope for envelope_after_s
                                     (for fault_ramp_after_s, then 0 when on_fault = ramp)
    clamped = clip(target, -M, +M)
    offset  = last + clip(clamped - last, -R*T, +R*T)

so no written offset is ever NaN or inf, and no two consecutive offsets
differ by more than ``R*T`` -- at start, at a model change, on recovery,
always. ``last`` is what the machine holds: :meth:`AxisSafety.load` re-seeds
it at start and whenever the offset point reads back something else (the
service, :mod:`compd.service.loop.offsets`).

The envelope (:mod:`compd.service.loop.envelope`): a target at the clamp, or
beyond the running model's calibrated output range by ``envelope_margin`` of
its span, for ``envelope_after_s`` on end is a fault like a faulted input's,
until the target is back inside.

The stage never starts outside the clamp: ``last`` is always finite and
within ``±M`` (:meth:`AxisSafety.load` clips a value beyond, NaN gives 0). An
offset point that reads back a value outside ``±M`` (500 um, or 3e38 in a
float32 register; to a count, or float32's precision), or one that is not
finite (NaN, inf), holds a value compd never wrote and no slew limit can
vouch for: it is a fault, not a seed. The axis then writes, on that tick and without a model
step, exactly the value :meth:`AxisSafety.recover` names for the configured
policy (``safety.on_offset_out_of_clamp``, :class:`OutOfClamp`):

- ``hold`` (default): ``last``, the last valid offset compd knows -- what it
  last wrote or read back within the clamp; at start the resumed offset
  (range-checked, :mod:`compd.service.store.state`), else 0 (no compensation);
- ``edge``: the clamp edge nearest the value read (``+M`` for 500 um or
  3e38, ``-M`` for -3000 um; a NaN as ``hold``), and the stage slews on from
  there towards the model's target;
- ``refuse``: nothing; the axis is not written until its point holds a value
  within the clamp again (set by the PLC or an operator), and the stage keeps ``last``.

That write is the one step the slew limit does not bound: the register
already holds a value outside the limits, and the jump back into them is the
correction. The tick is flagged faulted (level 2) with the readback-mismatch
bit, counted (``offsets_out_of_clamp``) and logged at ERROR once per episode
(:mod:`compd.service.loop.offsets`); a value read back within the clamp ends it.

The status word written beside the offsets lets the PLC supervise compd:

- bits 0-1: ``0`` ok, ``1`` degraded (an input held), ``2`` faulted (an axis frozen or ramping);
- bit 2 clamped, bit 3 slew-limited, bit 4 starting (no model output yet),
  bit 5 stopped (the last word written at shutdown), bit 6 a driver link down
  (or its device refusing writes: :attr:`~compd.service.loop.links.DriverLink.refusing_writes`),
  bit 7 blending to a newly loaded model;
- bits 8-31: one per configured signal, in config order, set while it is not OK;
- the bit after the last signal's (bit ``8 + n`` for ``n`` signals, when ``n < 24``):
  offset readback mismatch -- an axis's offset point did not hold what compd last
  wrote (a PLC restart that cleared it, another writer), and its slew limit was
  re-seeded from what it did hold; or, with level 2, it held a value outside the
  clamp or not finite, which was replaced as above. Placed there, not at bit 31, so that a
  16-bit status register has it for up to 7 signals; where the register has
  no bit left, the mismatch is only logged and counted;
- the bit after that (``8 + n + 1``): model fault -- the model's output is not
  finite, or a model failed and was unloaded (see :class:`~compd.service.loop.compensator.Compensator`),
  or an axis's target has been outside its envelope (at the clamp, or beyond
  the calibration) for ``envelope_after_s``: the model's output is not to be trusted.
  Where the register has no bit left for it, the fault shows as level 2 (faulted),
  in the log and in the counters.

The heartbeat counts ticks modulo 32768 (fits a PLC INT): when it stops
changing, the PLC knows compd is gone and falls back on its own.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from enum import IntEnum, StrEnum

from compd.service.loop.envelope import Envelope, EnvelopeSettings, EnvelopeWatch

HEARTBEAT_MODULO = 32_768
SIGNAL_BIT0 = 8
STATUS_BITS = 32


class Level(IntEnum):
    OK = 0
    DEGRADED = 1
    FAULTED = 2


class Flag(IntEnum):
    CLAMPED = 1 << 2
    SLEWING = 1 << 3
    STARTING = 1 << 4
    STOPPED = 1 << 5
    DRIVER_DOWN = 1 << 6
    BLENDING = 1 << 7


class FaultMode(StrEnum):
    """What an axis does while an input it depends on is faulted."""

    RAMP = "ramp"  # freeze, then ramp to zero at the slew limit after fault_ramp_after_s
    FREEZE = "freeze"  # hold the last offset until the input recovers


class OutOfClamp(StrEnum):
    """What an axis writes when its offset point reads back a value outside ``±M`` or not finite."""

    HOLD = "hold"  # the last valid offset compd knows (at start: the resumed one, else 0)
    EDGE = "edge"  # the clamp edge nearest the value read (NaN: as hold), slewing on from there
    REFUSE = "refuse"  # nothing, until the point holds a value within the clamp again


@dataclass(frozen=True)
class AxisLimits:
    max_offset_um: float
    max_rate_um_per_s: float


@dataclass(frozen=True, slots=True)
class AxisOutput:
    """One axis's offset this tick and what the stage did to it."""

    offset_um: float
    clamped: bool = False
    slewed: bool = False
    frozen: bool = False
    #: The target has been outside its envelope for ``envelope_after_s``: frozen or ramping as on a fault.
    outside: bool = False


class AxisSafety:
    """Clamp, slew limit, NaN guard, fault freeze/ramp and the envelope for one axis (see the module docstring)."""

    def __init__(
        self,
        limits: AxisLimits,
        period_s: float,
        *,
        on_fault: FaultMode = FaultMode.RAMP,
        fault_ramp_after_s: float = 60.0,
        offset_um: float = 0.0,
        on_out_of_clamp: OutOfClamp = OutOfClamp.HOLD,
        envelope: EnvelopeSettings | None = None,
    ) -> None:
        self.limits = limits
        self.max_step_um = limits.max_rate_um_per_s * period_s
        self.on_fault = FaultMode(on_fault)
        self.on_out_of_clamp = OutOfClamp(on_out_of_clamp)
        self.fault_ramp_after_s = fault_ramp_after_s
        self.offset_um = 0.0
        self.fault_since: float | None = None
        #: How long the target has been outside its envelope (the clamp until :meth:`calibrate`).
        consequence = (
            f"the offset ramps to 0 after {fault_ramp_after_s:g} s (safety.on_fault: ramp)"
            if self.on_fault is FaultMode.RAMP
            else "the offset is held (safety.on_fault: freeze)"
        )
        self.watch = EnvelopeWatch(
            envelope or EnvelopeSettings(), Envelope(limits.max_offset_um), consequence
        )
        self.load(offset_um)

    def calibrate(self, sign: float, output_range_um: tuple[float, float] | None) -> None:
        """Judge targets against the running model's calibrated output range (None: the clamp only).

        A new model's envelope applies from the next :meth:`step`; a spell
        outside goes on (its time counts on) if the target stays outside the new one.
        """
        settings = self.watch.settings
        self.watch.envelope = Envelope.of(
            self.limits.max_offset_um, sign, output_range_um, settings.margin
        )

    def load(self, offset_um: float) -> None:
        """Re-seed the last output (the offset the machine already holds), e.g. on resume.

        Never outside the clamp: a value beyond ``±M`` is clipped to it, a NaN
        or inf gives 0. Callers that may see such a value decide first what
        it means (:meth:`within`, :meth:`recover`).
        """
        m = self.limits.max_offset_um
        self.offset_um = min(max(offset_um, -m), m) if math.isfinite(offset_um) else 0.0

    def within(self, offset_um: float) -> bool:
        """Whether ``offset_um`` is finite and within the clamp ``±M``."""
        return abs(offset_um) <= self.limits.max_offset_um  # False for NaN and inf

    def recover(self, held_um: float) -> float | None:
        """The offset to write in place of ``held_um``, read back outside the clamp; None: write none.

        Seeds the stage with it (:class:`OutOfClamp`, the module docstring):
        ``hold`` and ``refuse`` keep the last valid offset, ``edge`` moves to the
        clamp edge nearest ``held_um``. The result is always within the clamp.
        """
        if self.on_out_of_clamp is OutOfClamp.REFUSE:
            return None
        if self.on_out_of_clamp is OutOfClamp.EDGE and not math.isnan(held_um):
            self.offset_um = math.copysign(self.limits.max_offset_um, held_um)
        return self.offset_um

    def hold(self) -> AxisOutput:
        """This tick's output without a model step: the last offset, as :meth:`recover` left it."""
        return AxisOutput(self.offset_um, frozen=True)

    def step(
        self, target_um: float, now_s: float, *, faulted: bool = False, measured_um: float = 0.0
    ) -> AxisOutput:
        """The offset to write for model target ``target_um`` at time ``now_s`` (s);
        ``measured_um``: the part of it probes measured on the machine (beyond the calibration
        on their evidence, not the model's)."""
        last = self.offset_um
        outside = self.watch.judge(now_s, target_um, measured_um)
        faulted = faulted or outside
        frozen = faulted or not math.isfinite(target_um)
        if faulted:
            if self.fault_since is None:
                self.fault_since = now_s
            ramping = (
                self.on_fault is FaultMode.RAMP
                and now_s - self.fault_since >= self.fault_ramp_after_s
            )
            target_um = 0.0 if ramping else last
        else:
            self.fault_since = None
            if not math.isfinite(target_um):
                target_um = last
        m = self.limits.max_offset_um
        clamped = min(max(target_um, -m), m)
        step = clamped - last
        slewed = abs(step) > self.max_step_um
        # Within the slew limit the clamped target is written exactly (not last + step,
        # which rounds): an unlimited offset is the model's value to the last bit.
        self.offset_um = last + math.copysign(self.max_step_um, step) if slewed else clamped
        return AxisOutput(self.offset_um, clamped != target_um, slewed, frozen, outside)


def status_word(
    level: Level,
    flags: Iterable[Flag],
    signal_bad: Sequence[bool],
    *,
    mismatch: bool = False,
    model_fault: bool = False,
) -> int:
    """Pack the level (bits 0-1), flags (bits 2-7), per-signal bits (8 on), mismatch and model-fault bits.

    The caller passes ``mismatch`` / ``model_fault`` only where the status point
    holds that bit (:func:`compd.service.config.writepoints.status_mismatch_bit`,
    :func:`~compd.service.config.writepoints.status_model_fault_bit`).
    """
    word = int(level)
    for flag in flags:
        word |= int(flag)
    for i, bad in enumerate(signal_bad):
        if bad:
            word |= 1 << (SIGNAL_BIT0 + i)
    if mismatch and (bit := mismatch_bit(len(signal_bad))) is not None:
        word |= 1 << bit
    if model_fault and (bit := model_fault_bit(len(signal_bad))) is not None:
        word |= 1 << bit
    return word


def mismatch_bit(n_signals: int) -> int | None:
    """The offset-readback-mismatch bit for ``n_signals`` signals: the next after theirs, if any is left."""
    bit = SIGNAL_BIT0 + n_signals
    return bit if bit < STATUS_BITS else None


def model_fault_bit(n_signals: int) -> int | None:
    """The model-fault bit for ``n_signals`` signals: the one after the mismatch bit, if any is left."""
    bit = SIGNAL_BIT0 + n_signals + 1
    return bit if bit < STATUS_BITS else None
