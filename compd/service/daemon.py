"""The compensation service's lifecycle: config -> model -> drivers -> loop -> shutdown.

Start-up validates everything before the first write to a machine: the
config (:mod:`compd.service.config.loading`), the model (the one last installed with
``compd model load``, else the config's), and that the two fit. It then
decides whether to resume the saved model state (:mod:`compd.service.store.state`), opens
the drivers, the control socket and the recorder, tells systemd it is ready
and runs the loop (:mod:`compd.service.loop.ticks`, :mod:`compd.service.loop.compensator`) until stopped.

While running, the control socket answers ``status`` (a snapshot of the
model, the last tick, the inputs and their health, and the counters) and
``load`` (switch to a model file the client sends: validated, compiled and
installed off the loop by :mod:`compd.service.control.modelload`, a bad one refused while
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
import math
import time
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any

import structlog

from compd.drivers.base import Driver
from compd.errors import CompdError
from compd.faultlog import Event, FaultLog
from compd.service import build
from compd.service.config.loading import Config
from compd.service.config.verifiable import UnverifiableCache
from compd.service.control.modelload import (
    ModelLoader,
    request_bytes,
    startup_slots,
    warn_unguarded,
)
from compd.service.control.peers import FdBudget
from compd.service.control.socket import ControlServer
from compd.service.identity import identity
from compd.service.loop.clock import Clock
from compd.service.loop.compensator import Compensator, TickRecord
from compd.service.loop.probemessages import probe_request
from compd.service.loop.safety import HEARTBEAT_MODULO
from compd.service.loop.snapshot import ModelId, TickSnapshot
from compd.service.loop.statusview import not_assured, status_snapshot, unverifiable_status
from compd.service.loop.subscribers import Subscribers, TickCallback
from compd.service.loop.ticks import TickTiming, run_periodic
from compd.service.notify import SystemdNotifier
from compd.service.recording.ticks import RecordingTicks
from compd.service.reload import Reloader
from compd.service.store.state import SavedState, resumable_state

if TYPE_CHECKING:
    from compd.service.fleet.telemetry import Telemetry
    from compd.service.http.server import StatusServer
    from compd.service.store.saver import StateSaver

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
        doc = config.doc
        now_unix = clock.wall()
        slot, fallback = startup_slots(config, now_unix)
        self.drivers = dict(drivers) if drivers is not None else config.build_drivers(clock.now)
        resume = resumable_state(config, slot, clock, now_unix) if slot is not None else None
        if slot is not None:
            warn_unguarded(config, slot)  # after the line naming the model
        self.resumed = resume is not None
        offsets = dict(resume.offsets_um) if resume is not None else {}
        self.links = {
            name: d.link(name, self.drivers[name], clock) for name, d in doc.drivers.items()
        }
        self.loader = ModelLoader(config, clock.wall)
        #: Probe measurements (config ``probes``): the log and learned parameters, the learning.
        self.probe_keeper = build.probe_keeper(
            config,
            background=background_saves,
            # a simulation's clock (virtual, sped up) runs ahead of the wall: its times do too
            real_time=getattr(clock, "time_scale", None) == 1.0,
        )
        self.probing = build.probe_learning(config, self.probe_keeper)
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
            probing=self.probing,
            pairs=doc.pairs(),
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
                {
                    "status": self._status,
                    "load": self.load_model,
                    "probe": self.take_probe,
                    "sensor": self.trust_sensor,
                },
                # A probe or a trusted sensor changes what the model compensates: whoever may
                # load a model may do them.
                access={
                    "load": doc.load_access.access(),
                    "probe": doc.load_access.access(),
                    "sensor": doc.load_access.access(),
                },
                budget=self.fd_budget,
            )
            if control
            else None
        )
        self._unverifiable_rows = UnverifiableCache()
        #: The last tick's snapshot (None before the first): what ``compd status`` and the page read.
        self.last: TickSnapshot | None = None
        self._model_id: ModelId | None = None  # the running model's, made once per model
        self.telemetry: Telemetry | None = None  # the page reads these while it is built
        self.recording: RecordingTicks | None = None
        self.saver: StateSaver | None = None  # the page reads it while it is built
        #: The loop's subscribers (:mod:`compd.service.build`), each told of every tick once.
        subscribed = build.tick_subscribers(
            config,
            self,
            notifier=self.notifier,
            saved_state=self.saved_state,
            background_saves=background_saves,
            identity=self._describe,
            wall=clock.wall,
            probe_keeper=self.probe_keeper,
        )
        self.recording = subscribed.recording
        self.recorder = None if self.recording is None else self.recording.recorder
        self.saver = saver = subscribed.saver
        #: MQTT telemetry (:mod:`compd.service.fleet.telemetry`) where the config asks for it.
        self.telemetry = subscribed.telemetry
        #: Metrics and the status page (config ``http``); None without one: nothing measured then.
        self.http: StatusServer | None = subscribed.http
        #: SIGHUP (:meth:`reload`): the config re-read, the recording re-opened.
        self.reloader = Reloader(
            config,
            self.recorder,
            self.notifier,
            ready=lambda: self.compensator.counters.ticks > 0,
            running=self._running_file,
        )
        if self.telemetry is not None:
            build.fleet_wiring(
                self.telemetry,
                config,
                reporters=[*self.links.values(), self.compensator],
                faults=[saver.fault] + ([] if self.recording is None else [self.recording.fault]),
                load_model=self.load_model,
                take_probe=None if self.probing is None else self.take_probe,
            )
        self.subscribers = Subscribers(
            doc.period_s, sink=None if self.telemetry is None else self.telemetry.event
        )
        for subscriber in subscribed.in_order():
            self.subscribers.add(subscriber)
        if on_tick is not None:
            self.subscribe(on_tick)

    async def run(self, *, duration_s: float | None = None) -> TickTiming:
        """Run until :meth:`stop` (or ``duration_s`` of clock time); then shut down cleanly."""
        # The control socket first: a second daemon on the same socket is refused
        # here, before it opens a driver, let alone writes to the machine.
        if self._control is not None:
            self.config.control_socket.parent.mkdir(parents=True, exist_ok=True)
            await self._control.start()
        try:
            await self.subscribers.begin()  # a page that cannot listen stops the start here
        except BaseException:
            if self._control is not None:
                await self._control.close()
            raise
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

    def _running_file(self) -> tuple[str, str] | None:
        """The running model's file and sha256, for the reload's check of the file on disk."""
        slot = self.compensator.running
        return None if slot is None else (str(slot.model_file.path), slot.sha256)

    def subscribe(self, on_tick: Callable[[TickRecord], None], name: str = "on_tick") -> None:
        """Call ``on_tick`` with every tick's record from now on (a live view, a test, the soak's witness)."""
        self.subscribers.add(TickCallback(name, on_tick))

    def saved_state(self) -> SavedState | None:
        """What the state saver writes: the active model's state and the offsets, now."""
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
        if self.saver is not None:
            self.saver.save_now()

    async def _tick(self, t_s: float) -> None:
        started_s = self.clock.now()
        # The thread's CPU clock is a system call, each a few microseconds after a sleep:
        # read only where a subscriber reads the tick's CPU (the metrics).
        read_cpu = self.subscribers.read_cpu
        cpu_started_s = time.thread_time() if read_cpu else math.nan
        real_started_s = time.perf_counter()
        record = await self.compensator.tick(t_s)
        running = self.compensator.running
        if running is None:
            model = None
        elif (model := self._model_id) is None or model.sha256 != running.sha256:
            model = self._model_id = ModelId(running.compiled.name, running.sha256)
        snapshot = TickSnapshot(
            record=record,
            ticks=self.compensator.counters.ticks,
            counters=TickSnapshot.frozen(self.counters()),
            model=model,
            lateness_s=self.timing.last_lateness_s,
            cpu_s=time.thread_time() - cpu_started_s if read_cpu else math.nan,
            started_real_s=real_started_s,
            on_time=self.clock.now() - started_s < self.config.doc.period_s,
        )
        self.last = snapshot
        self.subscribers.publish(snapshot)

    @property
    def recorder_fault(self) -> FaultLog | None:
        """The recorder's fault episodes (``active`` while it cannot write); None: nothing recorded."""
        return None if self.recording is None else self.recording.fault

    def leave_as_killed(self) -> None:
        """Make the end of ``run`` what SIGKILL would leave: sockets closed, nothing saved or written.

        For fault-injection soaks (:mod:`compd.sim.soak`) that kill and restart
        the service inside one process.
        """
        self._killed = True

    async def _shutdown(self) -> None:
        await self.reloader.close()
        killed = self._killed  # the OS closes the sockets; the socket file stays (stale)
        if not killed:
            self.notifier.stopping("saving state")
        await self.subscribers.end(killed=killed)
        if not killed:
            await self.compensator.write_stopped()
        await asyncio.gather(*(link.close() for link in self.links.values()))
        if self._control is not None:
            await self._control.close()
        if not killed:
            log.info(
                "stopped", ticks=self.compensator.counters.ticks, overruns=self.timing.overruns
            )

    async def load_model(self, message: dict[str, Any]) -> dict[str, Any]:
        """Check, install and switch to the model in ``message`` (the control socket's ``load``).

        ``message`` is :func:`compd.service.control.modelload.load_request`'s; raises
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

    async def take_probe(self, message: dict[str, Any]) -> dict[str, Any]:
        """The control socket's ``probe``: an axis's measured value (a gauge, a CMM), or a reset.

        ``{"axis": "Z", "measured_um": 3.2, "touched_at_unix_s": ..., "measures": "residue"}``
        is taken at the next tick (the touch time defaults to now); the reply
        says what the update did with it. ``{"reset": true}`` returns every
        output to the calibration's parameters and forgets what was learned.
        """
        probing = self.probing
        if probing is None:
            raise CompdError(
                f"{self.config.path}: probes are off: add a 'probes' section naming the axes "
                "probed (config/README.md, Probes)"
            )
        now_unix_s = self.clock.wall()
        if message.get("reset") is True:
            probing.reset()
            if probing.sha256 is not None and self.probe_keeper is not None:
                await self.probe_keeper.forget(probing.sha256)
            log.warning("probe updates reset: the calibration's parameters again", by="socket")
            return {"reset": True, "model_sha256": probing.sha256}
        request = probe_request(message, now_unix_s, probing.setup.measures)
        probing.offer(request)
        period_s = self.config.doc.period_s
        for _ in range(40):  # a few ticks: the answer says what the update did
            await asyncio.sleep(period_s / 10)
            if (answer := probing.answer(request)) is not None:
                axis: dict[str, Any] = probing.status(now_unix_s)["axes"][request.axis]
                return {"taken": True} | axis | {"last": answer.event_details()}
        return {"taken": False, "queued": True, "axis": request.axis}

    def clock_wall(self) -> float:
        """The loop clock's wall time now (unix s): on virtual time, the machine's."""
        return self.clock.wall()

    async def trust_sensor(self, message: dict[str, Any]) -> dict[str, Any]:
        """The control socket's ``sensor``: ``{"trust": NAME}``, a person vouching for a sensor
        compd stands in for (``compd sensor trust``); logged, with who asked."""
        name = message.get("trust")
        if not isinstance(name, str):
            raise CompdError('a sensor request is {"cmd": "sensor", "trust": "SIGNAL_NAME"}')
        answer = self.compensator.trust_signal(name)
        log.warning("sensor trust requested", signal=name, by="socket", answer=answer)
        return {"signal": name, "answer": answer}

    async def _status(self, message: dict[str, Any]) -> dict[str, Any]:
        return self.status()

    def status(self) -> dict[str, Any]:
        """A JSON-able snapshot (:mod:`compd.service.loop.statusview`)."""
        return status_snapshot(
            self.compensator,
            self.links,
            self.timing,
            clock=self.clock,
            units={name: signal.unit for name, signal in self.config.doc.signals.items()},
            resumed=self.resumed,
            started_unix_s=self.started_unix_s,
            counters=self.counters() if self.last is None else self.last.counters,
            telemetry=None if self.telemetry is None else self.telemetry.status_counters(),
        ) | {
            "probes": None if self.probing is None else self.probing.status(self.clock.wall()),
            "unverifiable": self._unverifiable(),
            # Where the state is saved and, while saves fail, why (a restart resumes from older).
            "state": None if self.saver is None else self.saver.status(),
        }

    def not_assured(self) -> list[str]:
        """What is not well though compensation goes on, one line each (``/healthz``'s warnings,
        systemd's status line): the state not saved; per axis the inputs whose wrong reading
        the sensors cannot see within the axis's tolerance (the status word's level says ``ok``
        meanwhile: it judges the readings, not what checks them), and the probes disagreeing
        with the model (the PLC's probe status bit 1)."""
        probing = self.probing
        return not_assured(
            self._unverifiable(),
            disagreeing=[]
            if probing is None
            else [a for a in probing.axes if probing.disagrees(a)],
            also=[] if self.saver is None or (p := self.saver.problem()) is None else [p],
        )

    def _unverifiable(self) -> list[dict[str, Any]]:
        """What the sensors cannot verify of the running model, per input and axis (none: no model)."""
        slot = self.compensator.running
        if slot is None:
            return []
        doc = self.config.doc
        rows = self._unverifiable_rows.rows(doc, slot.model_file, slot.compiled)
        return unverifiable_status(rows, {name: s.unit for name, s in doc.signals.items()})

    def _describe(self) -> dict[str, Any]:
        return identity(self.config, self.compensator.running, self.started_unix_s)

    def counters(self) -> dict[str, int]:
        """The service's counters, as ``compd status``, telemetry and the metrics give them."""
        counters = vars(self.compensator.counters) | {"overruns": self.timing.overruns}
        faults = reconnects = 0
        for link in self.links.values():
            faults += link.faults
            reconnects += link.reconnects
        counters["driver_faults"] = faults
        counters["reconnects"] = reconnects
        return counters
