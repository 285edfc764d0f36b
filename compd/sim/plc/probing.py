"""The simulated PLC's probe cycles: a touch probe on a datum ball, reported through registers (issue 35).

Per probed axis (``probes.axes.<axis>`` of the config) one
:class:`ProbeStation` runs the PLC's probe cycle. A cycle touches at its
start (machine time ``touched_s``) and, ``cycle_s`` later, writes the value,
the touch's unix time, then the counter plus one (the PLC's order: a client
that sees the new count finds the value already there). The value is what a
probe sees of the tool centre point at the touch::

    value_um = residue_um + noise_um + misprobe_um
    residue_um = true_error_um + applied_offset_um

with compensation active (``probes.measures: residue``; the offset carries
compd's sign, as in :mod:`compd.sim.plc.machine`), or ``true_error_um`` in
place of the residue where the PLC reports the drift alone
(``measures: thermal_error``). It is written raw, ``value_um / value_scale``,
and rounds to the register's resolution on the wire.

compd writes back the last count it took (``echo_address``) and its probe
status word (``status_address``: bit 0 "probe due", bit 1 "the model no
longer describes the machine"); the station keeps both in its
:class:`ProbeLog` and, with ``simulation.probes.when_due``, starts a cycle
when bit 0 is set (see :class:`compd.sim.plc.settings.SimProbesDoc`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from compd.sim.plc.settings import SimMisprobeDoc, SimProbesDoc

__all__ = [
    "COUNTER_MODULO",
    "PROBE_DUE_BIT",
    "ProbeCycle",
    "ProbeLog",
    "ProbeStation",
    "ServedProbe",
]

#: Bit 0 of compd's probe status word: a probe is due.
PROBE_DUE_BIT = 1
#: The counter runs 1, 2, ... 32767, 0, 1, ...: it fits any integer register, signed or not.
COUNTER_MODULO = 32768
#: Slack on the sample grid's times (s): a cycle due at 7200 s starts at the sample at 7200 s.
_EPS_S = 1e-6

CycleReason = Literal["timer", "due"]


@dataclass(frozen=True)
class ServedProbe:
    """A probed axis as the PLC serves it: its probe cycle's registers on ``driver`` (raw values)."""

    axis: str
    twin_axis: str
    driver: str
    value_address: str
    counter_address: str
    echo_address: str
    value_scale: float = 1.0
    touched_at_address: str | None = None
    status_address: str | None = None
    measures: Literal["residue", "thermal_error"] = "residue"


@dataclass(frozen=True)
class ProbeCycle:
    """One finished probe cycle: when it touched, the truth then, and what the PLC wrote.

    Times ``touched_s`` and ``written_s`` are machine time (s from the scenario's
    start); ``touched_at_unix_s`` is the stamp written for the touch. ``value_um``
    is what the probe reported (``raw_value * value_scale`` before the register's
    rounding), ``count`` the counter value written with it.
    """

    axis: str
    reason: CycleReason
    touched_s: float
    written_s: float
    touched_at_unix_s: float
    true_error_um: float
    offset_um: float
    residue_um: float
    noise_um: float
    misprobe_um: float
    value_um: float
    raw_value: float
    count: int


@dataclass
class ProbeLog:
    """What the PLC saw of compd on one axis's probe registers."""

    echo: int | None = None
    echo_writes: int = 0
    status_word: int | None = None
    status_writes: int = 0


@dataclass(frozen=True)
class _Touch:
    reason: CycleReason
    touched_s: float
    true_error_um: float
    offset_um: float
    noise_um: float
    misprobe_um: float


class ProbeStation:
    """One axis's probe cycle on the PLC: its schedule, the cycle under way, its registers."""

    def __init__(
        self,
        probe: ServedProbe,
        settings: SimProbesDoc,
        rng: np.random.Generator,
        misprobes: Sequence[SimMisprobeDoc] = (),
    ) -> None:
        self.probe = probe
        self.settings = settings
        self.rng = rng
        self.log = ProbeLog()
        self.count = 0
        self._misprobes = sorted(
            (m for m in misprobes if m.axis in (None, probe.axis)), key=lambda m: m.at_s
        )
        self._every_s = None if settings.every_h is None else settings.every_h * 3600.0
        self._timer_s = self._every_s  # the next timer cycle (machine s); None: no timer
        self._under_way: _Touch | None = None
        self._last_touch_s: float | None = None
        self._value_raw = 0.0
        self._touched_at_raw = 0.0

    def registers(self) -> dict[str, float]:
        """The raw values the PLC holds at the value, counter and touched-at addresses."""
        held = {
            self.probe.value_address: self._value_raw,
            self.probe.counter_address: float(self.count),
        }
        if self.probe.touched_at_address is not None:
            held[self.probe.touched_at_address] = self._touched_at_raw
        return held

    def written(self, address: str, raw: float) -> bool:
        """Take compd's write at ``address`` (echo or status word); False: not this axis's."""
        if address == self.probe.echo_address:
            self.log.echo = int(raw)
            self.log.echo_writes += 1
            return True
        if address == self.probe.status_address:
            self.log.status_word = int(raw)
            self.log.status_writes += 1
            return True
        return False

    def step(
        self, now_s: float, true_error_um: float, offset_um: float, wall0_unix_s: float
    ) -> ProbeCycle | None:
        """At machine time ``now_s``: finish the cycle under way if its time has come, start one if due.

        ``true_error_um`` and ``offset_um`` are the axis's thermal error and applied
        offset now (what a touch now would see); returns the cycle finished now, if any.
        """
        finished = None
        touch = self._under_way
        if touch is not None and now_s >= touch.touched_s + self.settings.cycle_s - _EPS_S:
            finished = self._write(touch, now_s, wall0_unix_s)
            self._under_way = None
        if self._under_way is None:
            reason = self._reason(now_s)
            if reason is not None:
                self._under_way = self._touch(reason, now_s, true_error_um, offset_um)
        return finished

    def _reason(self, now_s: float) -> CycleReason | None:
        timer_s, every_s = self._timer_s, self._every_s
        if timer_s is not None and every_s is not None and now_s >= timer_s - _EPS_S:
            while timer_s <= now_s + _EPS_S:  # absolute times: the timer never drifts
                timer_s += every_s
            self._timer_s = timer_s
            return "timer"
        word = self.log.status_word
        if self.settings.when_due and word is not None and word & PROBE_DUE_BIT:
            gap_s = self.settings.min_gap_h * 3600.0
            if self._last_touch_s is None or now_s - self._last_touch_s >= gap_s - _EPS_S:
                return "due"
        return None

    def _touch(
        self, reason: CycleReason, now_s: float, true_error_um: float, offset_um: float
    ) -> _Touch:
        self._last_touch_s = now_s
        noise_um = float(self.rng.normal(0.0, self.settings.noise_um))
        misprobe_um = 0.0
        while self._misprobes and self._misprobes[0].at_s <= now_s + _EPS_S:
            misprobe_um += self._misprobes.pop(0).error_um
        return _Touch(reason, now_s, true_error_um, offset_um, noise_um, misprobe_um)

    def _write(self, touch: _Touch, now_s: float, wall0_unix_s: float) -> ProbeCycle:
        residue_um = touch.true_error_um + touch.offset_um
        seen_um = residue_um if self.probe.measures == "residue" else touch.true_error_um
        value_um = seen_um + touch.noise_um + touch.misprobe_um
        self._value_raw = value_um / self.probe.value_scale
        self._touched_at_raw = wall0_unix_s + touch.touched_s
        self.count = (self.count + 1) % COUNTER_MODULO
        return ProbeCycle(
            axis=self.probe.axis,
            reason=touch.reason,
            touched_s=touch.touched_s,
            written_s=now_s,
            touched_at_unix_s=self._touched_at_raw,
            true_error_um=touch.true_error_um,
            offset_um=touch.offset_um,
            residue_um=residue_um,
            noise_um=touch.noise_um,
            misprobe_um=touch.misprobe_um,
            value_um=value_um,
            raw_value=self._value_raw,
            count=self.count,
        )
