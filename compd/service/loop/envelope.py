"""The offset's envelope: an axis asking for the clamp, or beyond its calibration, for minutes is faulted.

The clamp and the slew limit (:mod:`compd.service.loop.safety`) bound what
compd writes, not whether it is right: two sensors failing together can drive
the model to ask for the clamp for the rest of a shift, and the stage would
write it with status OK. Per axis, with its limit ``M = max_offset_um``, the
running model's calibrated output range ``[low, high]`` (um; the model file's
:meth:`~compd.files.modelfile.ModelFile.output_range`) and the margin
``m = envelope_margin * (high - low)``, the target offset
``t = sign * (output + probe adjustment)`` is *outside* its envelope when::

    |t| >= M                                  (at the clamp)
    t / sign < low - m  or  t / sign > high + m   (beyond the calibration)

A model file that records no output range (written by hand, or by a compd
before ``compd fit`` recorded one), or ``envelope_margin: null``, has the
clamp only. A target that is not finite (a model starting or faulted: its
own fault, :mod:`compd.service.loop.slots`) is not judged and ends a spell outside.

An axis outside its envelope for ``envelope_after_s`` on end is in an
*envelope fault* until its target is back inside: the stage treats it as an
input fault (``safety.on_fault``: frozen, then ramped to 0 at the slew limit
after ``fault_ramp_after_s`` with ``ramp``, held with ``freeze``), because an
offset extrapolated that far is more likely a sensor's fault than the
machine's heat, and a zero offset errs by no more than the machine would
without compd. The status is faulted (level 2) with the model-fault bit,
one ERROR line starts the episode and one INFO line ends it
(:mod:`compd.faultlog`), telemetry hears both, the ``envelope`` fault counter
counts it; ``compd status``, the page and ``/metrics`` say how long each axis
has been outside and why, from its first tick outside.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import structlog

from compd.faultlog import EventSink, FaultLog

log = structlog.get_logger("compd.service.loop.envelope")


@dataclass(frozen=True)
class EnvelopeSettings:
    """The ``safety`` section's envelope keys: the margin (a fraction of the calibration's span) and the delay."""

    #: None: the clamp only, whatever the model file records.
    margin: float | None = 0.25
    after_s: float = 300.0


@dataclass(frozen=True)
class Envelope:
    """Where an axis's target offset (um) is trusted: inside the clamp and the calibrated band.

    ``band_um`` is in the offset's own coordinates (the output's range times
    ``sign``, widened by the margin, low first); None: the clamp only.
    """

    max_offset_um: float
    band_um: tuple[float, float] | None = None

    @classmethod
    def of(
        cls,
        max_offset_um: float,
        sign: float,
        output_range_um: tuple[float, float] | None,
        margin: float | None,
    ) -> Envelope:
        """The envelope of an axis with clamp ``max_offset_um`` and ``sign``, for the model's output range."""
        if output_range_um is None or margin is None:
            return cls(max_offset_um)
        low, high = output_range_um
        widen = margin * (high - low)
        ends = sorted((sign * (low - widen), sign * (high + widen)))
        return cls(max_offset_um, (ends[0], ends[1]))

    def outside(self, target_um: float, measured_um: float = 0.0) -> str | None:
        """Why ``target_um`` is outside the envelope (``at the clamp``, ``beyond the calibration``); None: inside.

        ``measured_um``: the part of the target probes measured on the machine (their learned
        adjustment, in offset coordinates): the calibration's range bounds the model's own
        part only. A target that is not finite is not judged (None).
        """
        if not math.isfinite(target_um):
            return None
        if abs(target_um) >= self.max_offset_um:
            return "at the clamp"
        own = target_um - (measured_um if math.isfinite(measured_um) else 0.0)
        if self.band_um is not None and not self.band_um[0] <= own <= self.band_um[1]:
            return "beyond the calibration"
        return None

    def describe(self) -> str:
        """``clamp ±150 um, calibrated -33.4..+124.7 um`` (the band with its margin)."""
        said = f"clamp ±{self.max_offset_um:g} um"
        if self.band_um is None:
            return said + ", no calibrated range in the model file"
        low, high = self.band_um
        return said + f", calibrated {low:+.1f}..{high:+.1f} um"


class EnvelopeWatch:
    """One axis's time outside its envelope, and whether that is a fault yet (see the module docstring)."""

    def __init__(
        self,
        settings: EnvelopeSettings,
        envelope: Envelope,
        consequence: str = "the offset follows safety.on_fault",
    ) -> None:
        self.settings = settings
        self.envelope = envelope
        #: What the axis's offset does during a fault, in words (the stage's ``on_fault``).
        self.consequence = consequence
        #: When the current spell outside began (s, the loop's clock); None: inside.
        self.since_s: float | None = None
        #: Why the target is outside this tick (``at the clamp``...); None: inside.
        self.why: str | None = None
        #: The target this tick (um), as judged.
        self.target_um = math.nan
        #: How long the current spell has lasted (s), as of the last :meth:`judge`.
        self.outside_s = 0.0
        #: The spell has lasted ``after_s``: an envelope fault, until the target is back inside.
        self.faulted = False

    def judge(self, t_s: float, target_um: float, measured_um: float = 0.0) -> bool:
        """Take this tick's target (``measured_um`` of it the probes'); whether the axis is in an
        envelope fault now."""
        self.target_um = target_um
        self.why = self.envelope.outside(target_um, measured_um)
        if self.why is None:
            self.since_s, self.outside_s, self.faulted = None, 0.0, False
            return False
        if self.since_s is None:
            self.since_s = t_s
        self.outside_s = t_s - self.since_s
        self.faulted = self.outside_s >= self.settings.after_s
        return self.faulted

    def sentence(self, axis: str) -> str | None:
        """``Z asks for the clamp: target +163.2 um, clamp ±150 um, for 4 min, ...``; None while inside.

        It ends with when the spell becomes a fault, or once it is, with what
        the axis does then (:attr:`consequence`).
        """
        if self.why is None:
            return None
        target, envelope = self.target_um, self.envelope
        if self.why == "at the clamp":
            said = f"{axis} asks for the clamp: target {target:+.1f} um, clamp ±{envelope.max_offset_um:g} um"
        else:
            assert envelope.band_um is not None  # only a band puts a target beyond the calibration
            low, high = envelope.band_um
            said = (
                f"{axis} asks beyond its calibration: target {target:+.1f} um, "
                f"calibrated {low:+.1f}..{high:+.1f} um"
            )
        said += f", for {_duration(self.outside_s)}"
        if self.faulted:
            return f"{said}: faulted, {self.consequence}"
        return f"{said}; a fault after {_duration(self.settings.after_s)}"


class EnvelopeFaults:
    """Each axis's envelope-fault episodes: ERROR once at the start, INFO at the end, the sink told of both."""

    def __init__(self, axes: Iterable[str]) -> None:
        self.logs = {axis: FaultLog(log, axis=axis) for axis in axes}
        #: Episodes so far, all axes (the ``envelope_faults`` counter).
        self.episodes = 0

    def report_to(self, sink: EventSink) -> None:
        """Tell ``sink`` (the telemetry) of each episode's start and end."""
        for fault in self.logs.values():
            fault.sink = sink

    def update(self, axis: str, watch: EnvelopeWatch) -> None:
        """Log the start or the end of ``axis``'s episode, if this tick is one."""
        fault = self.logs[axis]
        if watch.faulted and not fault.active:
            self.episodes += 1
            fault.failed(
                "offset outside its envelope: the model is not trusted, the axis follows on_fault",
                why=watch.why,
                target_um=round(watch.target_um, 3),
                outside_s=round(watch.outside_s, 1),
                envelope=watch.envelope.describe(),
            )
        elif not watch.faulted and fault.active:
            fault.cleared("offset back inside its envelope", target_um=_rounded(watch.target_um))


def _rounded(value_um: float) -> float | None:
    return round(value_um, 3) if math.isfinite(value_um) else None


def _duration(seconds: float) -> str:
    """``45 s``, ``4 min``, ``1.5 h``."""
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds // 60:.0f} min"  # whole minutes passed: 299 s is 4 min, not yet 5
    return f"{seconds / 3600:.1f} h"
