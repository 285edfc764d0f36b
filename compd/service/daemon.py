"""The compensation service's lifecycle: config -> model -> drivers -> loop -> shutdown.

Start-up validates everything before the first write to a machine: the
config (:mod:`compd.service.config`), the model (the one last installed with
``compd model load``, else the config's), and that the two fit. It then
decides whether to resume the saved model state (:mod:`compd.service.state`), opens
the drivers, the control socket and the recorder, tells systemd it is ready
and runs the loop (:mod:`compd.service.ticks`, :mod:`compd.service.compensator`) until stopped.

While running, the control socket answers ``status`` (a snapshot of the
model, the last tick, the inputs and their health, and the counters) and
``load`` (switch to a model file the client sends: validated, compiled and
installed off the loop by :mod:`compd.service.modelload`, a bad one refused while
the running model goes on untouched; a good one blended in bumplessly by the
loop, and unloaded again should it fail while running). SIGHUP never stops it: the
config is re-read and checked, the recording re-opened (:mod:`compd.service.reload`).
Shutdown (SIGTERM, SIGINT, end of
``duration_s``) saves the state, writes a last status word with the STOPPED
bit (only after a first tick: a start that failed writes nothing), closes
the drivers and exits cleanly.
"""

from __future__ import annotations

import asyncio
import gc
import hashlib
import time
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any

import structlog

from compd.drivers.base import Driver
from compd.errors import RecorderError
from compd.faultlog import Event, FaultLog
from compd.service.clock import Clock
from compd.service.compensator import Compensator, TickRecord
from compd.service.config import Config
from compd.service.control import ControlServer
from compd.service.identity import column_units, identity, recording_metadata, systemd_summary
from compd.service.modelload import ModelLoader, request_bytes, startup_slots
from compd.service.notify import SystemdNotifier
from compd.service.peers import FdBudget
from compd.service.reload import Reloader
from compd.service.remoteload import COMMAND, MAX_PAYLOAD_BYTES, RemoteLoads
from compd.service.safety import HEARTBEAT_MODULO
from compd.service.seenrequests import FILE as SEEN_FILE
from compd.service.seenrequests import SeenRequests
from compd.service.state import MODELS_DIR, SavedState, resumable_state, save_state
from compd.service.statusview import status_snapshot
from compd.service.ticks import TickTiming, run_periodic

if TYPE_CHECKING:
    from compd.service.httpserver import StatusServer

log = structlog.get_logger("compd.service.daemon")

#: Input history kept for starting a newly loaded model warm (s): hours, as the machine's time constants.
HISTORY_S = 8 * 3600.0


class Service:
    """One running compensation service. Build, then ``await run()``.

    ``drivers`` may be given (tests keep a handle on the simulated machine);
    by default they are built from the config. Nothing is opened or written
    before :meth:`run`. ``background_saves=False`` writes the periodic state
    saves inside the tick instead of a worker thread: deterministic on a
    virtual clock, where a thousand ticks pass during one real fsync.
    """

    def __init__(
        self,
        config: Config,
        *,
        clock: Clock,
        drivers: Mapping[str, Driver] | None = None,
        notifier: SystemdNotifier | None = None,
        control: bool = True,
        on_tick: Callable[[TickRecord], None] | None = None,
        background_saves: bool = True,
    ) -> None:
        self.config = config
        self.background_saves = background_saves
        self.clock = clock
        self.notifier = notifier or SystemdNotifier(environ={})
        self.on_tick = on_tick
        doc = config.doc
        now_unix = clock.wall()
        slot, fallback = startup_slots(config, now_unix)
        self.drivers = dict(drivers) if drivers is not None else config.build_drivers(clock.now)
        resume = resumable_state(config, slot, clock, now_unix) if slot is not None else None
        self.resumed = resume is not None
        offsets = dict(resume.offsets_um) if resume is not None else {}
        self.links = {
            name: d.link(name, self.drivers[name], clock) for name, d in doc.drivers.items()
        }
        self.loader = ModelLoader(config, clock.wall)
        self.compensator = Compensator(
            signals=[s.point(name) for name, s in doc.signals.items()],
            monitors={name: s.monitor(name) for name, s in doc.signals.items()},
            axes=config.axis_points(),
            safety={
                axis: out.stage(doc.period_s, doc.safety, offset_um=offsets.get(axis, 0.0))
                for axis, out in doc.outputs.items()
            },
            links=self.links,
            model=slot,
            status=config.status_point(),
            blend_s=doc.blend_s,
            zero_now=doc.state.fresh_start == "now",
            wall_at=clock.wall_at,
            initial_state=resume.model_state if resume is not None else None,
            history_ticks=round(HISTORY_S / doc.period_s),
            schedule=doc.gain_schedule.scheduler() if doc.gain_schedule else None,
            on_model_failure=self.loader.failed,
            period_s=doc.period_s,
            plausibility=doc.plausibility.settings(),
            units={name: s.unit for name, s in doc.signals.items()},
        )
        if self.compensator.models is not None:
            self.compensator.models.fallback = fallback
        if resume is not None:
            self.compensator.heartbeat = resume.ticks % HEARTBEAT_MODULO
        self.timing = TickTiming()
        self.stop_event = asyncio.Event()
        self.started_unix_s = now_unix
        self._killed = False
        #: The descriptors the control socket and the HTTP server may spend on clients.
        self.fd_budget = FdBudget()
        self._control = (
            ControlServer(
                config.control_socket,
                {"status": self._status, "load": self.load_model},
                access={"load": doc.load_access.access()},
                budget=self.fd_budget,
            )
            if control
            else None
        )
        self.recorder = (
            doc.recorder.recorder(
                config.recorder_dir, recording_metadata(config), column_units(config)
            )
            if config.recorder_dir is not None
            else None
        )
        #: SIGHUP (:meth:`reload`): the config re-read, the recording re-opened.
        self.reloader = Reloader(
            config, self.recorder, self.notifier, ready=lambda: self.compensator.counters.ticks > 0
        )
        self._recorder_fault = FaultLog(log)
        self._save_fault = FaultLog(log)  # saves fail every save_every_ticks: log once
        self._saving: asyncio.Future[None] | None = None
        #: MQTT telemetry (:mod:`compd.service.telemetry`) where the config asks for it.
        self.telemetry = (
            doc.telemetry.telemetry(config.base_dir, identity=self._describe, wall=clock.wall)
            if doc.telemetry is not None
            else None
        )
        if self.telemetry is not None:
            sink = self.telemetry.event
            for link in self.links.values():
                link.report_to(sink)
            self.compensator.report_to(sink)
            self._recorder_fault.sink = self._save_fault.sink = sink
            if doc.telemetry is not None and doc.telemetry.accept_models:
                seen = SeenRequests(config.state_dir / SEEN_FILE)  # replays refused across restarts
                models = config.state_dir / MODELS_DIR
                remote = RemoteLoads(
                    self.load_model,
                    self.telemetry.reply,
                    sink,
                    seen=seen,
                    installed=lambda sha256: (models / f"{sha256}.yaml").is_file(),
                )
                self.telemetry.listen(COMMAND, remote.handle, max_bytes=MAX_PAYLOAD_BYTES)
                self.telemetry.take_desired(remote.take_desired)  # a machine back catches up
        #: Metrics and the status page (config ``http``); None without one: nothing measured then.
        self.http: StatusServer | None = (
            doc.http.server(self) if doc.http is not None and doc.http.enabled else None
        )

    async def run(self, *, duration_s: float | None = None) -> TickTiming:
        """Run until :meth:`stop` (or ``duration_s`` of clock time); then shut down cleanly."""
        # The control socket first: a second daemon on the same socket is refused
        # here, before it opens a driver, let alone writes to the machine.
        if self._control is not None:
            self.config.control_socket.parent.mkdir(parents=True, exist_ok=True)
            await self._control.start()
        if self.http is not None:
            try:
                await self.http.start()
            except BaseException:
                if self._control is not None:
                    await self._control.close()
                raise
        if self.telemetry is not None:
            self.telemetry.start()  # connects in the background: a broker away delays nothing
        await asyncio.gather(*(link.open() for link in self.links.values()))
        # Everything allocated so far (numpy, scipy, pandas, the model) lives as
        # long as the process: moved out of the collector's reach, a full
        # collection no longer walks it, which would stall a tick by ~100 ms.
        gc.collect()
        gc.freeze()
        try:
            await run_periodic(
                self.clock,
                self.config.doc.period_s,
                self._tick,
                stop=self.stop_event,
                duration_s=duration_s,
                timing=self.timing,
            )
        finally:
            await self._shutdown()
        return self.timing

    def stop(self) -> None:
        """Ask the loop to stop after the current tick (signal-handler safe)."""
        self.stop_event.set()

    def reload(self) -> None:
        """SIGHUP: re-read and check the config, re-open the recording; never stops (signal-handler safe)."""
        if not self.stop_event.is_set():
            self.reloader.request()

    def snapshot(self) -> SavedState | None:
        """What :meth:`save_state` writes: the active model's state and the offsets, now."""
        slot = self.compensator.running
        if slot is None:
            return None  # a data logger: no model state to save
        if slot.runner is None:
            return None  # nothing learned yet: keep whatever was saved before
        return SavedState(
            model_sha256=slot.sha256,
            model_name=slot.compiled.name,
            saved_at_unix_s=self.clock.wall(),
            model_state=slot.runner.state,
            offsets_um=self.compensator.held.known_um(),
            ticks=self.compensator.counters.ticks,
            saved_real_unix_s=time.time(),
        )

    def save_state(self) -> None:
        """Save now, in the calling thread (at shutdown)."""
        saved = self.snapshot()
        if saved is not None:
            self._write_state(saved)

    def _save_in_background(self) -> None:
        # fsync takes milliseconds on an SD card or a busy disk: the snapshot is
        # taken here, between ticks, and written by a worker thread so a save
        # never delays a tick. A save still running is not overtaken.
        if self._saving is not None and not self._saving.done():
            return
        saved = self.snapshot()
        if saved is not None and not self.background_saves:
            self._write_state(saved)
        elif saved is not None:
            self._saving = asyncio.ensure_future(asyncio.to_thread(self._write_state, saved))

    def _write_state(self, saved: SavedState) -> None:
        directory = str(self.config.state_dir)
        try:
            save_state(self.config.state_dir, saved)
        except OSError as exc:
            self._save_fault.failed("cannot save state", error=str(exc), directory=directory)
        else:
            self._save_fault.cleared("state saved again", directory=directory)

    async def _tick(self, t_s: float) -> None:
        started_s = self.clock.now()
        cpu_started_s, real_started_s = time.thread_time(), time.perf_counter()
        record = await self.compensator.tick(t_s)
        ticks = self.compensator.counters.ticks
        if ticks == 1:
            models = self.compensator.models
            self.notifier.ready(
                f"compensating with {models.active.compiled.name}"
                if models is not None
                else "recording (a data logger: nothing is written)"
            )
        # systemd's watchdog restarts a daemon whose loop has stalled or hangs in I/O: ping
        # only for a tick that finished within its period, so a loop that can no longer keep
        # its deadlines stops pinging. A machine that is merely unreachable (PLC off at
        # night) still gets healthy ticks: freezing the offsets is the right behaviour
        # there, and restarting would not help.
        if self.clock.now() - started_s < self.config.doc.period_s:
            self.notifier.watchdog()
        if ticks % self.config.doc.live_every_ticks == 0:
            self.notifier.status(systemd_summary(record))
        if self.recorder is not None:
            self._record(record)
        if ticks % self.config.doc.state.save_every_ticks == 0:
            self._save_in_background()
        telemetry = self.telemetry
        if telemetry is not None and ticks % telemetry.every_ticks == 0:
            running = self.compensator.running
            model = None if running is None else running.compiled.name
            telemetry.tick(record, self._tick_counters(), model)
        if self.http is not None:
            cpu_s = time.thread_time() - cpu_started_s
            self.http.tick(record, self.timing.last_lateness_s, cpu_s, real_started_s)
        if self.on_tick is not None:
            self.on_tick(record)

    def _record(self, record: TickRecord) -> None:
        assert self.recorder is not None
        row: dict[str, float | int | str] = {"t_s": record.t_s}
        row |= record.values
        # What each signal read, beside the value used (held, or estimated from the others).
        row |= {f"read.{k}": v for k, v in record.read.items()}
        row |= {f"health.{k}": int(v) for k, v in record.health.items()}
        row |= {f"model.{k}": v for k, v in record.model_outputs.items()}
        row |= {f"model.{k.replace('/', '.')}": v for k, v in record.contributions.items()}
        # What the devices acknowledged (NaN: not written), and what they held before the write.
        row |= {f"offset.{k}_um": v for k, v in record.acknowledged_um.items()}
        row |= {f"readback.{k}_um": v for k, v in record.readback_um.items()}
        row |= {f"gain.{k}": v for k, v in record.gains.items()}
        row |= {"status": record.status, "heartbeat": record.heartbeat}
        try:
            if (running := self.compensator.running) is not None:  # a logger names no model
                self.recorder.set_model(running.compiled.name, running.sha256)
            self.recorder.record(row, at_s=record.wall_unix_s)
        except RecorderError as exc:
            self._recorder_fault.failed("recorder failed", error=str(exc))
        else:
            if self._recorder_fault.active:  # once, at the end of the episode
                lost = self.recorder.take_lost_rows()
                self._recorder_fault.cleared("recorder works again", lost_rows=lost)

    @property
    def recorder_fault(self) -> FaultLog:
        """The recorder's fault episodes: ``active`` while it cannot write, ``episodes`` so far."""
        return self._recorder_fault

    def leave_as_killed(self) -> None:
        """Make the end of ``run`` what SIGKILL would leave: sockets closed, nothing saved or written.

        For fault-injection soaks (:mod:`compd.sim.soak`) that kill and restart
        the service inside one process.
        """
        self._killed = True

    async def _shutdown(self) -> None:
        await self.reloader.close()
        if self._killed:  # the OS closes the sockets; the socket file stays (stale)
            await asyncio.gather(*(link.close() for link in self.links.values()))
            if self._control is not None:
                await self._control.close()
            if self.http is not None:
                await self.http.close()
            return
        self.notifier.stopping("saving state")
        if self._saving is not None:
            await self._saving
        self.save_state()
        await self.compensator.write_stopped()
        await asyncio.gather(*(link.close() for link in self.links.values()))
        if self._control is not None:
            await self._control.close()
        if self.http is not None:
            await self.http.close()
        if self.recorder is not None:
            try:
                self.recorder.close()
            except RecorderError as exc:
                log.error("recorder close failed", error=str(exc))
        if self.telemetry is not None:
            await self.telemetry.stop(ticks=self.compensator.counters.ticks)
        log.info("stopped", ticks=self.compensator.counters.ticks, overruns=self.timing.overruns)

    async def load_model(self, message: dict[str, Any]) -> dict[str, Any]:
        """Check, install and switch to the model in ``message`` (the control socket's ``load``).

        ``message`` is :func:`compd.service.modelload.load_request`'s; raises
        CompdError if the model is refused, the running one untouched. The
        entry point for anything else that delivers a model (a fleet roll-out).
        """
        raw, _ = request_bytes(message)
        sha256 = hashlib.sha256(raw).hexdigest()
        comp = self.compensator
        for slot, state in ((comp.pending, "already_loading"), (comp.running, "already_running")):
            # The model that runs (or is about to) again: nothing to check, install or blend.
            if slot is not None and slot.sha256 == sha256:
                log.info(f"model load: {state.replace('_', ' ')}", name=slot.compiled.name)
                if comp.pending is None:  # the running model, with no switch under way
                    await self.loader.keep(slot)
                return {
                    "model": slot.compiled.name,
                    "sha256": sha256,
                    "installed": slot.model_file.path,
                    state: True,
                }
        slot = await self.loader.accept(message)
        self.compensator.load(slot)
        path = slot.model_file.path
        log.info("model loading", name=slot.compiled.name, sha256=slot.sha256, path=path)
        if self.telemetry is not None:
            details = {"model": slot.compiled.name, "sha256": slot.sha256, "path": path}
            self.telemetry.event(Event("model_loaded", "model loading", details))
        return {
            "model": slot.compiled.name,
            "sha256": slot.sha256,
            "installed": path,
            "blend_s": self.config.doc.blend_s,
        }

    async def _status(self, message: dict[str, Any]) -> dict[str, Any]:
        return self.status()

    def status(self) -> dict[str, Any]:
        """A JSON-able snapshot (:mod:`compd.service.statusview`)."""
        return status_snapshot(
            self.compensator,
            self.links,
            self.timing,
            clock=self.clock,
            units={name: signal.unit for name, signal in self.config.doc.signals.items()},
            resumed=self.resumed,
            started_unix_s=self.started_unix_s,
            telemetry=None if self.telemetry is None else self.telemetry.status_counters(),
        )

    def _describe(self) -> dict[str, Any]:
        return identity(self.config, self.compensator.running, self.started_unix_s)

    def _tick_counters(self) -> dict[str, int]:
        """The counters a telemetry status message carries (as ``compd status``'s)."""
        links = self.links.values()
        return vars(self.compensator.counters) | {
            "overruns": self.timing.overruns,
            "driver_faults": sum(link.faults for link in links),
            "reconnects": sum(link.reconnects for link in links),
        }
