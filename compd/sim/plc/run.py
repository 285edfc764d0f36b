"""Run compd against the simulated machine, in one process: ``compd run`` on a config with ``simulation``.

The machine's servers start first; then compd's service, unchanged, connects
to them through its normal drivers. One clock drives both: with
``time_scale=None`` a virtual clock that jumps from tick to tick as fast as
the I/O allows (a replay of an 8-hour shift takes seconds), else the real
clock ``time_scale`` times faster than real time. Either way the loop, the
drivers and the servers run exactly as they do on a machine.

:func:`serve_machine` is the machine alone (``compd simulate-machine``), on
its own real-time clock, for a compd running elsewhere.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from typing import Any

from compd.errors import CompdError
from compd.service.config.loading import Config
from compd.service.daemon import Service
from compd.service.loop.clock import Clock, RealClock, VirtualClock
from compd.service.loop.compensator import TickRecord
from compd.service.loop.links import DriverLink
from compd.service.loop.ticks import TickTiming, run_periodic
from compd.service.store.state import STATE_FILE
from compd.sim.plc.build import build_machine
from compd.sim.plc.machine import AxisSummary, MachineClock, SimulatedMachine
from compd.sim.plc.tally import SignalTally

#: Longest a virtual clock waits (real time) for a reconnect before time moves on.
SETTLE_MAX_S = 2.0


@dataclass
class SimulationResult:
    """What a simulated run achieved: per-axis errors, the daemon's counters, the machine."""

    summary: list[AxisSummary]
    status: dict[str, Any]
    machine: SimulatedMachine
    timing: TickTiming
    wall_s: float
    #: What the inputs went through, tick by tick (episodes, stand-in time, drift flags).
    signals: SignalTally | None = None

    @property
    def simulated_s(self) -> float:
        return self.machine.now_s


def base_clock(time_scale: float | None) -> Clock:
    """The virtual clock for ``None`` (as fast as possible), else the scaled real clock."""
    return VirtualClock(wall0_unix_s=time.time()) if time_scale is None else RealClock(time_scale)


async def run_simulation(
    config: Config,
    *,
    time_scale: float | None = None,
    duration_s: float | None = None,
    on_tick: Callable[[Service, SimulatedMachine, TickRecord], None] | None = None,
    service_hook: Callable[[Service], None] | None = None,
) -> SimulationResult:
    """Start the machine, run compd's service against it, stop both; see the module docstring.

    ``duration_s`` defaults to the scenario's length when ``simulation.stop_at_end``
    (else: until the service is stopped), less ``simulation.join_at_s``, the
    time the machine runs uncompensated before compd joins it (the summary
    covers the rest). The machine starts cold, so a model state
    saved by an earlier run is discarded (a model installed by ``compd model load``
    stays). ``on_tick`` sees every tick with the machine's truth; ``service_hook`` gets
    the service before it runs (signal handlers).
    """
    machine = build_machine(config)
    # The machine starts cold: a model state saved by an earlier run describes another machine.
    (config.state_dir / STATE_FILE).unlink(missing_ok=True)
    await start_machine(config, machine)
    join_s = machine.doc.join_at_s
    await machine.advance_to(join_s)  # the machine runs uncompensated until compd joins
    started = time.perf_counter()
    try:
        base = base_clock(time_scale)
        # Touch stamps in compd's time: clock time 0 is machine time join_s.
        machine.wall0_unix_s = base.wall_at(0.0) - join_s
        clock = MachineClock(base, machine)

        tally = SignalTally(config.doc.period_s)

        def tick(record: TickRecord) -> None:
            tally.observe(record, service.compensator.plausibility)
            if on_tick is not None:
                on_tick(service, machine, record)

        service = Service(
            config if time_scale is not None else saved_at_end_only(config),
            clock=clock,
            on_tick=tick,
            background_saves=time_scale is not None,
        )
        if time_scale is None:
            clock.settle = lambda: settle(service.links)
        if service.recording is not None:
            service.recording.extra_columns = lambda: truth_columns(machine)
        if service_hook is not None:
            service_hook(service)
        if duration_s is None and machine.doc.stop_at_end:
            duration_s = machine.duration_s - join_s
        timing = await service.run(duration_s=duration_s)
    finally:
        await machine.stop()
    return SimulationResult(
        summary=machine.summary(from_s=join_s),
        status=service.status(),
        machine=machine,
        timing=timing,
        wall_s=time.perf_counter() - started,
        signals=tally,
    )


#: ``state.save_every_ticks`` of a run on virtual time: never, before the save at its end.
NEVER_TICKS = 2**62


def saved_at_end_only(config: Config) -> Config:
    """``config`` with the state saved once, at the end: what a run on virtual time needs.

    Every ``save_every_ticks`` the service writes its state and fsyncs it, in the
    tick on virtual time (where a thousand ticks pass during one fsync); the
    8-hour quick start did so 480 times, 960 fsyncs, for a file the next run
    deletes (the machine starts cold). Saving at the end keeps what a later
    ``compd run`` or ``compd status`` sees, and every result.
    """
    state = config.doc.state.model_copy(update={"save_every_ticks": NEVER_TICKS})
    return replace(config, doc=config.doc.model_copy(update={"state": state}))


def truth_columns(machine: SimulatedMachine) -> dict[str, float]:
    """What a recording of a simulated run adds: per axis, what the axis is really off by (um).

    ``sim.residue.<axis>_um``: the twin's true thermal error plus the offset applied
    (the residue a perfect probe would read now), so a run's silent time (an error
    the status did not admit) can be counted from its recording alone.
    """
    return {f"sim.residue.{axis}_um": c for axis, (_, _, c) in machine.truth_now().items()}


async def start_machine(config: Config, machine: SimulatedMachine) -> None:
    """Start the machine's controllers; a port in use or a bad address is a CompdError naming the config."""
    try:
        await machine.start()
    except (OSError, RuntimeError, ValueError) as exc:
        await machine.stop()
        raise CompdError(
            f"{config.path}: the simulated machine cannot start its controllers: {exc}. "
            "Free the port, or give the driver another one: in the file (drivers.<name>.settings) "
            f"or for this run, e.g. --set drivers.{next(iter(config.doc.drivers))}.settings.port=N"
        ) from exc


async def settle(links: Mapping[str, DriverLink]) -> None:
    """Wait (real time, bounded) until no link is reconnecting: time stands still meanwhile."""
    deadline = time.monotonic() + SETTLE_MAX_S
    while any(link.connecting for link in links.values()) and time.monotonic() < deadline:
        await asyncio.sleep(0.001)


async def serve_machine(
    config: Config,
    *,
    time_scale: float = 1.0,
    stop: asyncio.Event | None = None,
    on_step: Callable[[SimulatedMachine], None] | None = None,
) -> SimulatedMachine:
    """The machine alone on the real clock (``time_scale`` faster), until ``stop`` or the scenario ends."""
    machine = build_machine(config)
    clock = RealClock(time_scale)
    machine.wall0_unix_s = clock.wall_at(0.0)
    stop = stop or asyncio.Event()

    async def step(t_s: float) -> None:
        await machine.advance_to(t_s)
        if on_step is not None:
            on_step(machine)

    await start_machine(config, machine)
    try:
        await run_periodic(
            clock, machine.sample_time_s, step, stop=stop, duration_s=machine.duration_s
        )
    finally:
        await machine.stop()
    return machine
