"""What each axis's offset point holds, as far as compd knows: readback, re-seeding, acknowledged writes.

The safety stage (:mod:`compd.service.loop.safety`) limits each step against the last
output; that bounds what the machine sees only if the last output is what
the machine holds. It is not after a PLC restart that cleared its offset
register, nor at a start whose saved state is missing, stale or wrong. So
per axis :class:`HeldOffsets` keeps the raw value the device holds:

- with readback (:attr:`AxisPoint.readback`), the value read at the start of
  each tick. When it is not what compd last wrote (nor a write that failed
  but landed), it is a *mismatch*: counted, flagged in the status word,
  logged once per episode. Either way the stage is re-seeded from it, so
  the next write is one slew step from what the PLC holds. While it cannot
  be read, the axis's offset is not written at all: never a step from a
  value nobody knows.
- a value read back outside the axis's clamp (:meth:`AxisPoint.within`), or
  not finite, is never a seed: it is a fault (:attr:`HeldOffsets.out_of_clamp`),
  logged at ERROR once per episode, and the axis writes what the stage's
  policy names instead (:meth:`compd.service.loop.safety.AxisSafety.recover`: the
  last valid offset, the clamp edge, or nothing). compd then knows no valid
  value the point holds until it reads one back or a write is acknowledged.
- without readback, the last acknowledged write; at start the stage's seed
  (a validated saved state, else 0).

A failed write re-seeds the stage from the held value too, so the first
write after a reconnect is one step from it. Integer encodings are limited
in whole counts (:meth:`AxisPoint.toward`): rounding never adds a count to a
slew step.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import structlog

from compd.faultlog import FaultLog
from compd.service.loop.safety import AxisSafety

log = structlog.get_logger("compd.service.loop.offsets")


@dataclass(frozen=True)
class AxisPoint:
    """Where an axis offset is written: ``round?(offset_um * scale)`` with ``offset_um = sign * output``.

    With ``readback``, the point is read each tick with the signals, and the
    safety stage slews from what the device holds, not from what compd wrote.
    """

    name: str
    model_output: str
    driver: str
    address: str
    sign: float = -1.0
    scale: float = 1.0
    integer: bool = False
    readback: bool = False

    def encode(self, offset_um: float) -> float:
        value = offset_um * self.scale
        return float(round(value)) if self.integer else value

    def decode(self, raw: float) -> float:
        """The offset (um) a raw value at the point stands for."""
        return raw / self.scale

    def within(self, raw: float, max_offset_um: float) -> bool:
        """Whether ``raw`` is finite and within ``±max_offset_um`` as written (to a count, or float32's precision)."""
        if not math.isfinite(raw):
            return False
        reach = abs(self.encode(max_offset_um))
        return abs(raw) <= reach or self.same(abs(raw), reach)

    def same(self, raw: float, other: float) -> bool:
        """Two raw values are one offset: equal counts, or equal to float32's precision."""
        if self.integer:
            return round(raw) == round(other)
        return math.isclose(raw, other, rel_tol=1e-6, abs_tol=1e-9)

    def toward(self, raw: float, held: float | None, max_step_um: float) -> float:
        """``raw``, at most as many whole counts from ``held`` as one slew step holds.

        Rounding to counts could otherwise add a count to a slew step;
        :mod:`compd.service.config.writepoints` makes sure one step holds at least one count.
        """
        if not self.integer or held is None:
            return raw
        counts = math.floor(max_step_um * self.scale * (1 + 1e-9))
        return min(max(raw, held - counts), held + counts)


class HeldOffsets:
    """Per axis, the raw value its device holds (None: unknown), and the stage seeded from it."""

    def __init__(self, axes: Sequence[AxisPoint], safety: Mapping[str, AxisSafety]) -> None:
        self.axes = list(axes)
        self.safety = safety
        #: Raw value per axis as far as compd knows; a readback axis is unknown until read.
        self.raw: dict[str, float | None] = {
            a.name: None if a.readback else a.encode(safety[a.name].offset_um) for a in self.axes
        }
        #: A write that failed: the device may have applied it all the same.
        self._sent: dict[str, float | None] = {a.name: None for a in self.axes}
        self._mismatching: set[str] = set()
        #: Readback axes whose value could not be read this tick: not written.
        self.unknown: set[str] = set()
        #: Readback axes whose value this tick was outside the clamp or not finite, and the
        #: offset (um) written instead (None: none, ``refuse``); reset by each :meth:`read_back`.
        self.out_of_clamp: dict[str, float | None] = {}
        #: One fault-episode log per axis for values read back outside the clamp.
        self.clamp_faults = {a.name: FaultLog(log, axis=a.name) for a in self.axes}

    def read_back(self, held: Mapping[str, float]) -> int:
        """Take in the raw offsets read back (by axis name); returns how many mismatched."""
        mismatches = 0
        self.out_of_clamp = {}
        for axis in self.axes:
            if not axis.readback:
                continue
            raw = held.get(axis.name)
            if raw is None:
                self._unreadable(axis)
                continue
            if axis.name in self.unknown:
                self.unknown.discard(axis.name)
                log.info("offset read back again", axis=axis.name, held_um=axis.decode(raw))
            stage, fault = self.safety[axis.name], self.clamp_faults[axis.name]
            if not axis.within(raw, stage.limits.max_offset_um):
                self._out_of_clamp(axis, raw)
                continue
            known, sent = self.raw[axis.name], self._sent[axis.name]
            recovered = fault.active
            fault.cleared("offset read back within the clamp again", held_um=axis.decode(raw))
            if known is None:
                if not recovered:
                    log.info("offset seeded from the PLC", axis=axis.name, held_um=axis.decode(raw))
            elif not axis.same(raw, known) and not (sent is not None and axis.same(raw, sent)):
                mismatches += 1
                self._mismatch(axis, raw, known)
            elif axis.name in self._mismatching:
                self._mismatching.discard(axis.name)
                log.info("offset read back as written again", axis=axis.name)
            if not axis.same(raw, axis.encode(stage.offset_um)):
                stage.load(axis.decode(raw))
            self.raw[axis.name], self._sent[axis.name] = raw, None
        return mismatches

    def to_write(self, offsets_um: Mapping[str, float]) -> dict[str, float]:
        """Raw value to write per axis: the stage's offset, in counts no further than a step; unknown axes left out."""
        raws = {}
        for axis in self.axes:
            refused = axis.name in self.out_of_clamp and self.out_of_clamp[axis.name] is None
            if axis.name not in self.unknown and not refused:
                step_um = self.safety[axis.name].max_step_um
                raw = axis.encode(offsets_um[axis.name])
                raws[axis.name] = axis.toward(raw, self.raw[axis.name], step_um)
        return raws

    def written(self, raws: Mapping[str, float], ok: Mapping[str, bool]) -> dict[str, float]:
        """Record a write (``ok`` by driver); returns the offsets (um) acknowledged, by axis."""
        acknowledged = {}
        for axis in self.axes:
            if axis.name not in raws:
                continue
            if ok[axis.driver]:
                self.raw[axis.name] = raws[axis.name]
                acknowledged[axis.name] = axis.decode(raws[axis.name])
                continue
            self._sent[axis.name] = raws[axis.name]
            if (held := self.raw[axis.name]) is not None:
                self.safety[axis.name].load(axis.decode(held))
        return acknowledged

    def known_um(self) -> dict[str, float]:
        """The offset (um) each axis's device is known to hold; unknown axes left out."""
        return {a.name: a.decode(raw) for a in self.axes if (raw := self.raw[a.name]) is not None}

    def _unreadable(self, axis: AxisPoint) -> None:
        if axis.name not in self.unknown:
            log.warning(
                "offset not written: reading it back failed, so what the PLC holds is unknown",
                axis=axis.name,
                address=axis.address,
            )
        self.unknown.add(axis.name)

    def _out_of_clamp(self, axis: AxisPoint, raw: float) -> None:
        """A value compd cannot have written: replaced as the stage's policy says, never a seed."""
        stage = self.safety[axis.name]
        held_um = axis.decode(raw)
        self.out_of_clamp[axis.name] = written_um = stage.recover(held_um)
        # What the point holds is no valid offset: nothing to slew from, nothing to save.
        self.raw[axis.name] = self._sent[axis.name] = None
        self.clamp_faults[axis.name].failed(
            "offset read back outside the clamp or not finite: not followed, "
            + ("left unwritten" if written_um is None else "replaced"),
            held_um=held_um,
            max_offset_um=stage.limits.max_offset_um,
            policy=str(stage.on_out_of_clamp),
            written_um=written_um,
        )

    def _mismatch(self, axis: AxisPoint, raw: float, known: float) -> None:
        if axis.name in self._mismatching:
            log.debug("offset read back differs again", axis=axis.name, held_um=axis.decode(raw))
            return
        self._mismatching.add(axis.name)
        log.error(
            "offset read back is not what was written: slewing from what the PLC holds",
            axis=axis.name,
            held_um=axis.decode(raw),
            written_um=axis.decode(known),
        )
