"""The soak's judge on the PLC's side (:mod:`compd.sim.soak`): every value the offset register receives.

The :class:`Witness` sits on the PLC's write path and judges each write
against what the register held just before (after any reset): writes
outside the clamp, steps above the slew limit (from a value within the
clamp: the write that replaces a value outside it is a correction, counted
apart, and must land within the clamp), heartbeats (counted), and offsets the service reports as acknowledged
(:attr:`~compd.service.loop.compensator.TickRecord.acknowledged_um`) that the PLC never
received. The counts go into a :class:`SoakResult`.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field

from compd.service.loop.compensator import TickRecord
from compd.sim.soaksensors import SensorEpisode

#: Slack on a step, um: the register holds whole counts, so only float noise.
STEP_TOLERANCE_UM = 1e-6


@dataclass
class SoakResult:
    """What the soak saw: faults by kind, the counts judged, what explains them, and what sensor faults cost."""

    faults: Counter[str] = field(default_factory=Counter)
    crashes: int = 0
    slew_violations: int = 0
    #: Offsets written outside ``±max_offset_um`` (or not finite).
    outside_clamp: int = 0
    #: Writes that replaced a value outside the clamp the register held (not judged as steps).
    corrections: int = 0
    unacknowledged: int = 0
    #: Writes that reached the PLC while the service counted them failed (allowed: re-seeded).
    landed_unacknowledged: int = 0
    offsets_received: int = 0
    largest_step_um: float = 0.0
    ticks: int = 0
    services: int = 0
    bad_models_refused: int = 0
    bad_models_accepted: int = 0
    offset_mismatches: int = 0
    #: Offsets the services read back outside the clamp (their ``offsets_out_of_clamp``).
    offsets_out_of_clamp: int = 0
    #: The roll-out command taken as sent (1), then its retained copy and replays: refused / taken again.
    rollouts_taken: int = 0
    rollouts_refused: int = 0
    rollouts_taken_again: int = 0
    #: ``malformed``: the driver fault episodes the services saw while the PLC's replies were
    #: malformed, and driver exceptions outside the DriverError contract (all faults).
    malformed_faults: int = 0
    driver_bugs: int = 0
    #: ``slow_clients`` (:mod:`compd.sim.soakclients`): the clients opened, the status requests
    #: answered, turned away ``busy`` and unanswered, the ticks whose heartbeat the PLC missed,
    #: and the longest real time between two ticks during an episode (s).
    slow_clients: int = 0
    status_answered: int = 0
    status_busy: int = 0
    status_unanswered: int = 0
    heartbeats_missed: int = 0
    largest_tick_gap_s: float = 0.0
    #: ``slow_clients`` over HTTP: the ``/metrics`` scrapes answered and unanswered meanwhile.
    scrapes_answered: int = 0
    scrapes_unanswered: int = 0
    #: ``sighup``: the reloads the services took (:mod:`compd.sim.soakreload`).
    reloads_done: int = 0
    #: ``state_corrupt``: the state files the services set aside as unreadable.
    states_set_aside: int = 0
    #: The sensor faults, each with its window's largest error and the fault-free run's
    #: (:mod:`compd.sim.soaksensors`); the reference run's wall time (s).
    sensor_faults: list[SensorEpisode] = field(default_factory=list)
    reference_wall_s: float = 0.0
    #: Why each bad model was refused (the daemon's reply).
    refusals: list[str] = field(default_factory=list)
    simulated_s: float = 0.0
    wall_s: float = 0.0
    errors: list[str] = field(default_factory=list)

    @property
    def passed(self) -> bool:
        return (
            self.crashes == 0
            and self.slew_violations == 0
            and self.outside_clamp == 0
            and self.unacknowledged == 0
            and self.bad_models_accepted == 0
            and self.rollouts_taken_again == 0
            and self.driver_bugs == 0
            and self.status_unanswered == 0
            and self.heartbeats_missed == 0
            and self.scrapes_unanswered == 0
            and self.reloads_done == self.faults["sighup"]
        )


class Witness:
    """The PLC's side: every value the offset register receives, judged against what it held."""

    def __init__(
        self,
        address: str,
        scale: float,
        max_step_um: float,
        result: SoakResult,
        *,
        max_offset_um: float = math.inf,
        heartbeat_address: str | None = None,
    ) -> None:
        self.address = address
        self.heartbeat_address = heartbeat_address
        #: Heartbeats the PLC received (the soak's slow-client episodes count them).
        self.heartbeats = 0
        self.scale = scale
        self.max_step_um = max_step_um
        self.max_offset_um = max_offset_um
        self.result = result
        self.held_raw = 0.0  # the register starts cleared
        self.programming = False  # the PLC's own program is writing
        self._since_tick: list[float] = []

    def sink(self, inner: Callable[[str, float], None]) -> Callable[[str, float], None]:
        def written(address: str, raw: float) -> None:
            if address == self.address:
                self._offset(raw)
            elif address == self.heartbeat_address:
                self.heartbeats += 1
            inner(address, raw)

        return written

    def _offset(self, raw: float) -> None:
        if not self.programming:
            step_um = abs(raw - self.held_raw) / self.scale
            if not self._within(raw):
                self.result.outside_clamp += 1
                self.result.errors.append(f"offset {raw / self.scale:g} um outside the clamp")
            if not self._within(self.held_raw):
                self.result.corrections += 1
            else:
                self.result.largest_step_um = max(self.result.largest_step_um, step_um)
                if step_um > self.max_step_um + STEP_TOLERANCE_UM:
                    self.result.slew_violations += 1
                    self.result.errors.append(
                        f"step of {step_um:g} um: {self.held_raw / self.scale:g} -> "
                        f"{raw / self.scale:g}"
                    )
            self.result.offsets_received += 1
            self._since_tick.append(raw)
        self.held_raw = raw

    def _within(self, raw: float) -> bool:
        """Within the clamp, to half a count (the register holds whole counts)."""
        return abs(raw / self.scale) <= self.max_offset_um + 0.5 / self.scale

    def abandon(self) -> None:
        """The service died mid-tick: what reached the PLC meanwhile was never acknowledged."""
        self.result.landed_unacknowledged += len(self._since_tick)
        self._since_tick = []

    def tick(self, record: TickRecord, axis: str) -> None:
        """One tick's acknowledged offset must be among the values the PLC received during it."""
        received, self._since_tick = self._since_tick, []
        self.result.ticks += 1
        acknowledged = record.acknowledged_um.get(axis, math.nan)
        if math.isfinite(acknowledged):
            if not any(round(acknowledged * self.scale) == round(r) for r in received):
                self.result.unacknowledged += 1
                self.result.errors.append(f"t={record.t_s:g} s: {acknowledged} um never received")
        else:
            self.result.landed_unacknowledged += len(received)
