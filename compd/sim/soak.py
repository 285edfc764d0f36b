"""A fault-injection soak: compd's service against the simulated machine, a fault every few minutes.

compd's real :class:`~compd.service.daemon.Service` runs against the simulated
machine's Modbus TCP PLC on 127.0.0.1, on virtual time, for a whole shift.
Every few (virtual) minutes a fault drawn with a seeded generator strikes:

- ``plc_reset``: the PLC restarts and its offset register is cleared to 0;
- ``link_drop``: the PLC's server is gone for a while, then back;
- ``garbage``: another server holds the port for a while, answering bytes
  that are not Modbus (random bytes, a broken frame header), then the PLC returns;
- ``state_corrupt``: the service is stopped, its state file corrupted
  (garbage, truncated, NaN, an offset of 1e9 um, ``"ticks": 1e400``, an
  integer of 5,000 digits, ...), and started again;
- ``bad_model``: a model file that must be refused (a non-finite gain, a
  huge ``nk``, garbage bytes) is sent to ``load`` over the control socket;
- ``kill``: the service is dropped as SIGKILL leaves a process -- no final
  state save, no STOPPED word, its sockets closed -- between two ticks or in
  the middle of a write (the PLC applies it, compd never hears back), and a
  new one is started on the same state directory;
- ``out_of_clamp``: the PLC's own program puts a value outside the clamp into
  the offset register (500 um, -3000 um, the int32 extremes), which compd must
  replace with a value within it, never slew from;
- ``malformed``: for a while, half the PLC's replies are well-framed Modbus
  of the wrong shape (too short or long, a lying byte count, another
  function, an unknown exception code, a PDU cut short): driver faults, which
  the link reconnects from, never an exception out of the loop;
- ``slow_clients``: for a while, hundreds of clients hold half-sent requests
  on the status page's HTTP port, the control socket or both, while the
  status is asked for over both and ``/metrics`` scraped (:mod:`compd.sim.soakclients`);
- ``sighup``: the service is told to reload, as SIGHUP does, its config file
  unchanged, changed or broken meanwhile (:mod:`compd.sim.soakreload`);
- ``sensor_offset``, ``glitch``, ``stuck``, ``wire_break``: a model input's
  sensor, each in turn, reads +15 or -25 degC off the truth, 60 degC for 40 s,
  its last value, or 327.67, -200 or NaN, for a while
  (:mod:`compd.sim.soaksensors`, through the simulated machine's own fault injection).

The draw and the makings of each fault are :mod:`compd.sim.soakfaults`; the
witness below is :mod:`compd.sim.soakwitness`. The services run as
deployed: control socket, HTTP server (status page and metrics), recorder.

A witness on the PLC's write path sees every value the offset register
receives and judges it against what the register held just before (after
any reset): the soak counts crashes (an exception out of the service, or a
service that cannot be built), writes outside the clamp, steps above the
slew limit (``max_rate_um_per_s * period_s``) from a value within the clamp,
and offsets the service reports as acknowledged
(:attr:`~compd.service.loop.compensator.TickRecord.acknowledged_um`, what the
recorder writes) that the PLC never received. Targets: 0, 0, 0, 0. A
service that ends before the shift does is a crash too (a reload must never
stop it).

With sensor faults, the same config and seed first runs without faults, and
each sensor fault is measured against it: the compensated error's excess over
the fault-free run in the fault's window (:mod:`compd.sim.soaksensors`).
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import math
import random
import time
from collections.abc import Awaitable, Callable, Sequence
from pathlib import Path
from typing import Any

from compd.drivers.modbus.driver import ModbusDriver
from compd.drivers.modbus.settings import ModbusSettings
from compd.errors import CompdError
from compd.service.config.loading import Config
from compd.service.control.modelload import load_request
from compd.service.control.socket import request
from compd.service.daemon import Service
from compd.service.loop.clock import VirtualClock
from compd.service.loop.compensator import TickRecord
from compd.service.store.state import STATE_FILE
from compd.sim.plc.build import build_machine, served_addresses
from compd.sim.plc.machine import MachineClock, SimulatedMachine
from compd.sim.plc.modbus import ModbusPlcServer
from compd.sim.plc.run import settle, start_machine
from compd.sim.soakclients import SlowClients
from compd.sim.soakconfig import soak_config
from compd.sim.soakfaults import (
    OUT_OF_CLAMP_UM,
    RESTARTS,
    SENSOR_KINDS,
    DyingDriver,
    Fault,
    bad_models,
    corrupt_state,
    garbage_server,
    malformed_replies,
)
from compd.sim.soakreload import sighup
from compd.sim.soakrollouts import deliver, rollout_command
from compd.sim.soaksensors import SensorFaults
from compd.sim.soakwitness import SoakResult, Witness

__all__ = ["RESTART_S", "Soak", "SoakClock", "soak_config"]

#: Virtual seconds between the end of one service and the start of the next.
RESTART_S = 3.0


class SoakClock(MachineClock):
    """The machine's clock, which also strikes the faults that fall due as time moves on."""

    def __init__(
        self, machine: SimulatedMachine, strike: Callable[[float], Awaitable[None]]
    ) -> None:
        super().__init__(VirtualClock(wall0_unix_s=time.time()), machine)
        machine.wall0_unix_s = self.base.wall_at(0.0) - machine.doc.join_at_s  # touch stamps
        self.strike = strike

    async def sleep_until(self, t: float) -> None:
        await super().sleep_until(t)
        await self.strike(t)


class Soak:
    """One soak run over ``config`` (a simulated Modbus machine); :meth:`run` returns the result.

    ``reference``: with sensor faults, run the shift without faults first and
    measure each sensor fault's excess over it (else the excess is NaN).
    """

    def __init__(
        self, config: Config, faults: Sequence[Fault], *, seed: int = 0, reference: bool = True
    ) -> None:
        self.config = config
        self.faults = list(faults)
        self.drawn = tuple(faults)
        self.rng = random.Random(seed)
        self.result = SoakResult()
        doc = config.doc
        (self.axis, out), *_ = doc.outputs.items()
        self.driver = out.driver
        self.machine = build_machine(config)
        self.witness = Witness(
            out.address,
            out.encoding.scale,
            out.max_rate_um_per_s * doc.period_s,
            self.result,
            max_offset_um=out.max_offset_um,
            heartbeat_address=doc.status.heartbeat_address if doc.status is not None else None,
        )
        self._replace_server()
        self.clock = SoakClock(self.machine, self._strike)
        self.service: Service | None = None
        self._restart: asyncio.Future[str] | None = None
        self._loads: list[asyncio.Task[None]] = []
        self._ends: list[tuple[float, Callable[[], Awaitable[None]]]] = []
        assert config.model_path is not None, "a soak runs a compensating config, not a logger"
        self._bad = bad_models(config.model_path.read_bytes())
        self._rollout = rollout_command(config.model_path.read_bytes())
        self._variant = ""
        self._slow: SlowClients | None = None
        self.sensors = SensorFaults(config, self.machine, self.axis, self.result.sensor_faults)
        self._reference = reference and any(f.kind in SENSOR_KINDS for f in self.faults)

    def _replace_server(self) -> None:
        """The PLC's Modbus server again, its write sink passing through the witness."""
        name = self.driver
        inputs, outputs = served_addresses(self.config.doc, name)
        settings = self.config.driver_settings[name]
        assert isinstance(settings, ModbusSettings)  # the soak's machine is a Modbus PLC
        self.server = ModbusPlcServer(
            settings,
            inputs=inputs,
            outputs=outputs,
            on_write=self.witness.sink(self.machine.on_write(name)),
            base_dir=self.config.base_dir,
        )
        self.machine.servers[name] = self.server

    async def run(self) -> SoakResult:
        if self._reference:
            started = time.perf_counter()
            await self.sensors.run_reference()
            self.result.reference_wall_s = time.perf_counter() - started
        started = time.perf_counter()
        (self.config.state_dir / STATE_FILE).unlink(missing_ok=True)
        await start_machine(self.config, self.machine)
        try:
            await self._services(self.machine.duration_s)
            await asyncio.gather(*self._loads, return_exceptions=True)
            await self._end_due(math.inf)  # a drop or garbage server outlasting the shift
        finally:
            await self.machine.stop()
        self.result.simulated_s = self.machine.now_s
        self.result.wall_s = time.perf_counter() - started
        self.result.states_set_aside = len(
            list(self.config.state_dir.glob(f"{STATE_FILE}.corrupt-*"))
        )
        self.sensors.measure(self.drawn)
        return self.result

    async def _services(self, end_s: float) -> None:
        while self.clock.now() < end_s:
            try:
                service = Service(
                    self.config, clock=self.clock, on_tick=self._tick, background_saves=False
                )
            except Exception as exc:  # a service that cannot start is a crash, then a retry
                self._crash(f"start failed: {exc!r}")
                await self._downtime(RESTART_S)
                continue
            self.result.services += 1
            self.service = service
            self.clock.settle = functools.partial(settle, service.links)
            self._restart = asyncio.get_running_loop().create_future()
            task = asyncio.create_task(service.run(duration_s=end_s - self.clock.now()))
            first = self.result.services == 1  # the roll-out's retained copy, at every start
            rollout = deliver(
                service, self.config.state_dir, self._rollout, self.result, first=first
            )
            self._loads.append(asyncio.create_task(rollout))
            waits: set[asyncio.Future[Any]] = {task, self._restart}
            await asyncio.wait(waits, return_when=asyncio.FIRST_COMPLETED)
            how = self._restart.result() if self._restart.done() else None
            self._restart = None
            if how == "kill":
                await self._kill(service, task)
            else:
                with contextlib.suppress(Exception):
                    await task
                if task.exception() is not None:
                    self._crash(f"service failed: {task.exception()!r}")
            counters = service.compensator.counters
            self.result.offset_mismatches += counters.offset_mismatches
            self.result.offsets_out_of_clamp += counters.offsets_out_of_clamp
            self.result.driver_bugs += sum(link.unexpected for link in service.links.values())
            self.service = None
            if how is None and task.exception() is None:
                if self.clock.now() < end_s - self.config.doc.period_s:
                    self._crash("the service stopped before the end of the shift")
                return  # the shift is over
            if how == "state_corrupt":
                self._corrupt_state()
            await self._downtime(RESTART_S)

    async def _downtime(self, seconds: float) -> None:
        """No service for ``seconds``: the machine and the PLC faults under way go on."""
        self.clock.settle = None
        target = self.clock.now() + seconds
        while self.clock.now() < target:
            await MachineClock.sleep_until(self.clock, min(target, self.clock.now() + 1.0))
            await self._end_due(self.clock.now())

    async def _kill(self, service: Service, task: asyncio.Task[Any]) -> None:
        """What SIGKILL leaves: nothing more of the service runs; the OS closes its sockets."""
        service.leave_as_killed()
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task
        self.witness.abandon()

    def _crash(self, why: str) -> None:
        self.result.crashes += 1
        self.result.errors.append(f"t={self.clock.now():g} s: {why}")

    def _tick(self, record: TickRecord) -> None:
        self.witness.tick(record, self.axis)
        self.sensors.tick(record)
        if self._slow is not None:
            self._slow.tick(record)

    def _corrupt_state(self) -> None:
        path = self.config.state_dir / STATE_FILE
        saved = path.read_bytes() if path.exists() else b"{}"
        path.write_bytes(corrupt_state(saved, self._variant))

    # -- faults, struck from the clock between ticks ------------------------

    async def _strike(self, t_s: float) -> None:
        await self._end_due(t_s)
        restart = self._restart
        while self.faults and self.faults[0].at_s <= t_s and self.service is not None:
            if restart is None or restart.done():
                return  # this service is on its way out: the fault waits for the next one
            fault = self.faults.pop(0)
            self.result.faults[fault.kind] += 1
            if fault.kind == "kill" and fault.variant == "mid_write":
                self._kill_in_next_write(self.service)
                return
            if fault.kind in RESTARTS:
                self._variant = fault.variant
                if fault.kind == "state_corrupt":
                    self.service.stop()  # a clean stop: the next tick does not come
                restart.set_result(fault.kind)
                if fault.kind == "kill":
                    await asyncio.Event().wait()  # frozen until killed
                return
            await self._begin(fault, t_s)

    def _kill_in_next_write(self, service: Service) -> None:
        """The service dies in its next write: the PLC applies it, compd never hears the reply."""
        link = service.links[self.driver]
        assert self._restart is not None
        restart: asyncio.Future[str] = self._restart

        def die() -> bool:
            if restart.done():  # stopped by another fault first: no kill
                return False
            restart.set_result("kill")
            return True

        link.driver = DyingDriver(link.driver, die)

    async def _begin(self, fault: Fault, t_s: float) -> None:
        if fault.kind == "plc_reset":
            await self.server.stop()
            await self.server.start()
            await self._program(0.0)
        elif fault.kind == "link_drop":
            await self.server.stop()
            self._ends.append((t_s + fault.duration_s, self.server.start))
        elif fault.kind == "garbage":
            await self.server.stop()
            host, port = self.server.address
            impostor = await garbage_server(host, port, fault.variant, self.rng.random())

            async def back() -> None:
                impostor.close()
                await impostor.wait_closed()
                await self.server.start()

            self._ends.append((t_s + fault.duration_s, back))
        elif fault.kind == "out_of_clamp":
            await self._program(OUT_OF_CLAMP_UM[fault.variant])
        elif fault.kind == "bad_model":
            assert self.service is not None
            self._loads.append(asyncio.create_task(self._load_bad(self.service, fault.variant)))
        elif fault.kind == "malformed":
            await self._malformed(fault, t_s)
        elif fault.kind == "slow_clients":
            await self._slow_clients(fault, t_s)
        elif fault.kind == "sighup":
            assert self.service is not None
            await sighup(self.service, fault.variant, self.result)
        elif fault.kind in SENSOR_KINDS:
            self.sensors.strike(fault)

    async def _malformed(self, fault: Fault, t_s: float) -> None:
        """Half the PLC's replies malformed for a while; the driver faults the service saw meanwhile."""
        service = self.service
        assert service is not None
        link = service.links[self.driver]
        faults = link.faults
        self.server.rewrite_reply = malformed_replies(fault.variant, self.rng.random())

        async def back() -> None:
            self.server.rewrite_reply = None
            if self.service is service:  # the fault outlasting the service counts nothing
                self.result.malformed_faults += link.faults - faults

        self._ends.append((t_s + fault.duration_s, back))

    async def _slow_clients(self, fault: Fault, t_s: float) -> None:
        """Slow clients on the service's HTTP port and control socket for a while; the status asked for."""
        service = self.service
        assert service is not None
        span = (t_s, t_s + fault.duration_s)
        self._slow = SlowClients(fault.variant, span, self.witness, self.result)
        self._loads.append(await self._slow.begin(service, lambda: self.service is service))
        self._ends.append((span[1], self._slow.end))

    async def _end_due(self, t_s: float) -> None:
        due = [end for end in self._ends if end[0] <= t_s]
        for end in due:
            self._ends.remove(end)
            await end[1]()

    async def _program(self, offset_um: float) -> None:
        """The PLC's own program sets its offset register (here: the reset of a restart)."""
        settings = self.config.driver_settings[self.driver]
        assert isinstance(settings, ModbusSettings)
        driver = ModbusDriver(settings, now=self.clock.now, base_dir=Path())
        await driver.open()
        self.witness.programming = True
        try:
            out = self.config.doc.outputs[self.axis]
            await driver.write({out.address: round(offset_um * out.encoding.scale)})
        finally:
            self.witness.programming = False
            await driver.close()

    async def _load_bad(self, service: Service, variant: str) -> None:
        """Send a bad model to ``load`` over the control socket; it must be refused."""
        try:
            reply = await request(
                self.config.control_socket,
                load_request(self._bad[variant], f"bad-{variant}.yaml"),
                timeout_s=60.0,
            )
        except CompdError:  # the service went away meanwhile (a kill): no verdict
            return
        if reply.get("ok"):
            self.result.bad_models_accepted += 1
            self.result.errors.append(f"bad model {variant} accepted: {reply}")
        else:
            self.result.bad_models_refused += 1
            self.result.refusals.append(str(reply.get("error", "")))
