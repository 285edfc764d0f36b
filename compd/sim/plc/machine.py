"""The simulated machine: the thermal twin, its sensors and its PLC, with the truth kept.

Every ``sample_time_s`` of clock time the machine steps the twin with the
scenario's inputs, reads its sensors (lag, offset, noise) and publishes each
configured signal, converted back to the raw value its address carries
(``raw = (value - offset) / scale``), to the server of that signal's driver.
Offsets compd writes are applied to the tool centre point from the moment
they arrive, as a PLC adds them at its next cycle, so the machine knows
exactly what the compensation achieved::

    compensated_error_um = true_thermal_error_um + applied_offset_um

(the offset carries compd's sign: it cancels the predicted drift). Faults of
the ``simulation`` section are applied on the same clock: a sensor stuck, NaN
or out of range; a controller unreachable for a while or restarted.

Where the config has probe registers (``probes.axes``), the PLC runs probe
cycles on the same clock (:mod:`compd.sim.plc.probing`, on a timer or when
compd's probe-due bit asks, per ``simulation.probes``); every finished cycle
is kept in :attr:`SimulatedMachine.probe_cycles`, with the truth it saw.

The machine is advanced by the clock (:class:`MachineClock`), not by a task
of its own, so a replay on a virtual clock is deterministic: the machine is
always exactly at the time of compd's tick.
"""

from __future__ import annotations

import asyncio
import bisect
import math
import time
from collections.abc import Awaitable, Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import structlog

from compd.service.loop.clock import Clock
from compd.sim.partners import PartnerBank
from compd.sim.plc.probing import ProbeCycle, ProbeStation, ServedProbe
from compd.sim.plc.server import PlcServer
from compd.sim.plc.settings import SimFaultDoc, SimulationDoc
from compd.sim.scenarios import scenario_inputs
from compd.sim.sensors import SensorBank, SensorSet
from compd.sim.thermal import MachineInputs, MachineTwin, TwinState
from compd.sim.variants import machine_variant

log = structlog.get_logger("compd.sim.plc")

AXES = ("x", "y", "z")


@dataclass(frozen=True)
class ServedSignal:
    """A config signal as the PLC serves it: twin column -> raw value at ``driver``/``address``."""

    name: str
    driver: str
    address: str
    column: str
    scale: float = 1.0
    offset: float = 0.0

    def raw(self, value: float) -> float:
        return (value - self.offset) / self.scale


@dataclass(frozen=True)
class ServedAxis:
    """A compensated axis: the raw value written at ``driver``/``address`` is ``offset_um * scale``."""

    name: str
    driver: str
    address: str
    twin_axis: str
    scale: float = 1.0


@dataclass(frozen=True)
class AxisSummary:
    """One axis over the run: the thermal error without and with compensation, um."""

    axis: str
    rms_uncompensated_um: float
    rms_compensated_um: float
    pp_uncompensated_um: float
    pp_compensated_um: float
    max_uncompensated_um: float
    max_compensated_um: float
    max_offset_step_um: float

    @property
    def reduction_pct(self) -> float:
        """RMS reduction: 100 (1 - compensated / uncompensated)."""
        if self.rms_uncompensated_um == 0:
            return 0.0
        return 100.0 * (1.0 - self.rms_compensated_um / self.rms_uncompensated_um)


@dataclass
class PlcLog:
    """What the PLC saw of compd: writes, status words, heartbeats."""

    writes: int = 0
    status_word: int | None = None
    heartbeat: int | None = None
    heartbeat_changes: int = 0
    heartbeat_repeats: int = 0
    heartbeat_timeouts: int = 0
    last_heartbeat_s: float = 0.0
    faults_injected: list[str] = field(default_factory=list)


class SimulatedMachine:
    """The twin along a scenario behind ``servers`` (one per driver name); see the module docstring."""

    def __init__(
        self,
        doc: SimulationDoc,
        *,
        signals: list[ServedSignal],
        axes: list[ServedAxis],
        servers: Mapping[str, PlcServer],
        status: tuple[str, str, str] | None = None,
        probes: Sequence[ServedProbe] = (),
    ) -> None:
        self.doc = doc
        self.signals = signals
        self.axes = {(a.driver, a.address): a for a in axes}
        self.axis_names = [a.name for a in axes]
        self.servers = dict(servers)
        self.status = status  # (driver, status address, heartbeat address)
        params = machine_variant(doc.variant)
        self.sample_time_s = doc.sample_time_s
        self.inputs = scenario_inputs(doc.scenario, doc.hours, doc.seed, doc.sample_time_s)
        self.steps = len(self.inputs) - 1
        first = MachineInputs(
            float(self.inputs.T_ambient_degC[0]), float(self.inputs.T_coolant_degC[0])
        )
        self.twin = MachineTwin(first, sample_time_s=doc.sample_time_s, params=params)
        rng = np.random.default_rng([doc.seed, 1])
        self.sensors = SensorBank(SensorSet.draw(rng), doc.sample_time_s, rng, params)
        #: The second sensors beside critical ones, on a stream of their own (the others unchanged).
        self.partners = PartnerBank(doc.sample_time_s, np.random.default_rng([doc.seed, 3]))
        self.k = 0  # samples stepped
        n = self.steps + 1
        self.time_s = np.arange(n) * doc.sample_time_s
        self.true_um = np.zeros((n, 3))
        self.offset_um = np.zeros((n, 3))
        self.applied_um = dict.fromkeys(AXES, 0.0)
        self.row: dict[str, float] = {}
        self.plc = PlcLog()
        self._faults = sorted(doc.faults, key=lambda f: f.at_s)
        self._active: list[SimFaultDoc] = []
        self._stuck: dict[str, float] = {}
        self._down: set[str] = set()
        self._heartbeat_lost = False
        self._by_driver: dict[str, list[ServedSignal]] = {}
        for s in signals:
            self._by_driver.setdefault(s.driver, []).append(s)
        #: Config axis -> its probe cycle on the PLC (``probes.axes``, ``simulation.probes``).
        self.probe_stations = {
            p.axis: ProbeStation(
                p, doc.probes, np.random.default_rng([doc.seed, 2, i]), doc.probes.misprobes
            )
            for i, p in enumerate(probes)
        }
        #: Every finished probe cycle, all axes, in the order they wrote their registers.
        self.probe_cycles: list[ProbeCycle] = []
        #: Unix time (s) of machine time 0: the touch stamps' origin. The run sets it
        #: from the clock compd runs on (``run_simulation``, ``serve_machine``).
        self.wall0_unix_s = time.time() - doc.join_at_s

    # -- life cycle -------------------------------------------------------

    @property
    def duration_s(self) -> float:
        return self.steps * self.sample_time_s

    @property
    def now_s(self) -> float:
        return self.k * self.sample_time_s

    async def start(self) -> None:
        """Start every server, serving the machine at rest (time 0)."""
        self.row = self._read(self.twin.state, self.inputs.at(0))
        self._publish()
        await asyncio.gather(*(server.start() for server in self.servers.values()))

    async def stop(self) -> None:
        await asyncio.gather(*(server.stop() for server in self.servers.values()))

    def on_write(self, driver: str) -> Callable[[str, float], None]:
        """The write sink of ``driver``'s server."""

        def written(address: str, raw: float) -> None:
            self.plc.writes += 1
            axis = self.axes.get((driver, address))
            if axis is not None:
                self.applied_um[axis.twin_axis] = raw / axis.scale
            elif self.status is not None and (driver, address) == self.status[:2]:
                self.plc.status_word = int(raw)
            elif self.status is not None and (driver, address) == (self.status[0], self.status[2]):
                self._heartbeat(int(raw))
            else:  # a probe's echo or status word
                for station in self.probe_stations.values():
                    if station.probe.driver == driver and station.written(address, raw):
                        break

        return written

    def _heartbeat(self, value: int) -> None:
        if value == self.plc.heartbeat:
            self.plc.heartbeat_repeats += 1
        else:
            self.plc.heartbeat_changes += 1
            self.plc.last_heartbeat_s = self.now_s
        self.plc.heartbeat = value

    def inject(self, fault: SimFaultDoc) -> None:
        """Add ``fault`` to those to come (a soak's, drawn as it runs): it strikes at its ``at_s``.

        One due now strikes at the next step (the service reads it at its next tick).
        """
        bisect.insort(self._faults, fault, key=lambda f: f.at_s)

    # -- time -------------------------------------------------------------

    async def advance_to(self, t_s: float) -> None:
        """Step the twin up to clock time ``t_s`` (never past the scenario's end)."""
        target = min(self.steps, math.floor(t_s / self.sample_time_s + 1e-9))
        while self.k < target:
            await self._faults_at(self.now_s)
            self._record_offsets(self.k)
            u = self.inputs.at(self.k)
            state = self.twin.step(u)
            self.k += 1
            self.true_um[self.k] = state.displacement_um
            self.row = self._read(state, u)
            self._supervise()
            self._probe()
        self._record_offsets(self.k)
        await self._faults_at(self.now_s)
        self._publish()

    def _read(self, state: TwinState, u: MachineInputs) -> dict[str, float]:
        """Every quantity the PLC can serve now: the logged columns and the partner sensors."""
        return {**self.sensors.read(state, u), **self.partners.read(state, u)}

    def _record_offsets(self, k: int) -> None:
        self.offset_um[k] = [self.applied_um[a] for a in AXES]

    def _supervise(self) -> None:
        silent = self.now_s - self.plc.last_heartbeat_s > self.doc.heartbeat_timeout_s
        if self.status is not None and silent and not self._heartbeat_lost:
            self.plc.heartbeat_timeouts += 1
        self._heartbeat_lost = silent

    def _probe(self) -> None:
        for station in self.probe_stations.values():
            twin_axis = station.probe.twin_axis
            true_um = float(self.true_um[self.k, AXES.index(twin_axis)])
            cycle = station.step(self.now_s, true_um, self.applied_um[twin_axis], self.wall0_unix_s)
            if cycle is not None:
                self.probe_cycles.append(cycle)
                log.info(
                    "simulated probe cycle",
                    axis=cycle.axis,
                    count=cycle.count,
                    touched_s=cycle.touched_s,
                    value_um=round(cycle.value_um, 3),
                )

    def _publish(self) -> None:
        for driver, server in self.servers.items():
            if driver in self._down:
                continue
            values = {s.address: s.raw(self._value(s)) for s in self._by_driver.get(driver, ())}
            for station in self.probe_stations.values():
                if station.probe.driver == driver:
                    values.update(station.registers())
            if values:
                server.publish(values)

    def _value(self, s: ServedSignal) -> float:
        value = self.row[s.column]
        for fault in self._active:
            if fault.signal != s.name:
                continue
            if fault.kind == "stuck":
                return self._stuck.setdefault(s.name, value)
            if fault.kind == "nan":
                return math.nan
            if fault.kind == "value" and fault.value is not None:
                return fault.value
            if fault.kind == "offset" and fault.value is not None:
                return value + fault.value
            if fault.kind == "drift" and fault.rate_per_h is not None:
                return value + fault.rate_per_h * (self.now_s - fault.at_s) / 3600.0
        return value

    async def _faults_at(self, t_s: float) -> None:
        ending = [f for f in self._active if t_s >= f.at_s + f.duration_s]
        for fault in ending:
            self._active.remove(fault)
            if fault.kind == "drop" and fault.driver is not None:
                await self.servers[fault.driver].start()
                self._down.discard(fault.driver)
                log.info("simulated controller back", driver=fault.driver, t_s=t_s)
            if fault.signal is not None:
                self._stuck.pop(fault.signal, None)
        while self._faults and self._faults[0].at_s <= t_s:
            fault = self._faults.pop(0)
            self.plc.faults_injected.append(_describe(fault))
            log.info("simulated fault", fault=_describe(fault), t_s=t_s)
            if fault.kind == "restart" and fault.driver is not None:
                await self.servers[fault.driver].stop()
                await self.servers[fault.driver].start()
                continue
            if fault.kind == "drop" and fault.driver is not None:
                await self.servers[fault.driver].stop()
                self._down.add(fault.driver)
            self._active.append(fault)

    # -- truth ------------------------------------------------------------

    def truth_now(self) -> dict[str, tuple[float, float, float]]:
        """Per config axis: (true thermal error, applied offset, compensated error) now, um."""
        out = {}
        for axis in self.axes.values():
            i = AXES.index(axis.twin_axis)
            true = float(self.true_um[self.k, i])
            offset = self.applied_um[axis.twin_axis]
            out[axis.name] = (true, offset, true + offset)
        return out

    def summary(self, from_s: float = 0.0, to_s: float = math.inf) -> list[AxisSummary]:
        """Per config axis over ``[from_s, min(to_s, now)]``: RMS, peak-to-peak and max |error|, um."""
        first = min(self.k, math.ceil(from_s / self.sample_time_s - 1e-9))
        last = (
            min(self.k, math.floor(to_s / self.sample_time_s + 1e-9)) if to_s < math.inf else self.k
        )
        rows = []
        for axis in self.axes.values():
            i = AXES.index(axis.twin_axis)
            true = self.true_um[first : last + 1, i]
            offset = self.offset_um[first : last + 1, i]
            comp = true + offset
            rows.append(
                AxisSummary(
                    axis=axis.name,
                    rms_uncompensated_um=_rms(true),
                    rms_compensated_um=_rms(comp),
                    pp_uncompensated_um=float(np.ptp(true)),
                    pp_compensated_um=float(np.ptp(comp)),
                    max_uncompensated_um=float(np.max(np.abs(true))),
                    max_compensated_um=float(np.max(np.abs(comp))),
                    max_offset_step_um=float(np.max(np.abs(np.diff(offset)), initial=0.0)),
                )
            )
        return rows


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if x.size else 0.0


def _describe(fault: SimFaultDoc) -> str:
    target = fault.signal or fault.driver
    text = f"{fault.kind} {target} at {fault.at_s:g} s"
    return text + (f" for {fault.duration_s:g} s" if fault.duration_s else "")


class MachineClock:
    """A clock that brings the simulated machine to each time compd's loop wakes up at.

    Clock time 0 is machine time ``simulation.join_at_s``: compd joins a machine
    that has run (uncompensated) until then. ``settle`` (optional) is awaited before time moves on: on a virtual clock
    it lets background I/O (a driver reconnecting) finish first, as it would
    within one period in real time.
    """

    def __init__(
        self,
        base: Clock,
        machine: SimulatedMachine,
        settle: Callable[[], Awaitable[None]] | None = None,
    ) -> None:
        self.base = base
        self.machine = machine
        self.settle = settle

    @property
    def time_scale(self) -> float | None:
        """The base clock's ``time_scale``; None on virtual time (``--time-scale max``)."""
        scale: float | None = getattr(self.base, "time_scale", None)
        return scale

    def now(self) -> float:
        return self.base.now()

    def wall(self) -> float:
        return self.base.wall()

    def wall_at(self, t: float) -> float:
        return self.base.wall_at(t)

    async def sleep_until(self, t: float) -> None:
        if self.settle is not None:
            await self.settle()
        await self.base.sleep_until(t)
        await self.machine.advance_to(self.machine.doc.join_at_s + self.base.now())


__all__ = [
    "AxisSummary",
    "MachineClock",
    "PlcLog",
    "ProbeCycle",
    "ServedAxis",
    "ServedSignal",
    "SimulatedMachine",
]
