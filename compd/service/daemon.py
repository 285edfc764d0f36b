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
loop, and unloaded again should it fail while running). Shutdown (SIGTERM, SIGINT, end of
``duration_s``) saves the state, writes a last status word with the STOPPED
bit (only after a first tick: a start that failed writes nothing), closes
the drivers and exits cleanly.
"""

from __future__ import annotations

import asyncio
import gc
import math
import time
from collections.abc import Callable, Mapping
from datetime import UTC, datetime
from typing import Any

import structlog

from compd.drivers.base import Driver
from compd.drivers.registry import load_driver_type
from compd.errors import RecorderError
from compd.faultlog import FaultLog
from compd.service.clock import Clock
from compd.service.compensator import Compensator, TickRecord
from compd.service.config import Config
from compd.service.control import Access, ControlServer
from compd.service.links import DriverLink
from compd.service.modelload import ModelLoader, startup_slots
from compd.service.notify import SystemdNotifier
from compd.service.offsets import AxisPoint
from compd.service.points import SignalPoint, StatusPoint
from compd.service.recorder import Recorder
from compd.service.safety import HEARTBEAT_MODULO, AxisLimits, AxisSafety, FaultMode
from compd.service.schedule import GainScheduler
from compd.service.signals import Checks, SignalMonitor
from compd.service.state import (
    SavedState,
    StateError,
    load_state,
    resume_decision,
    save_state,
)
from compd.service.ticks import TickTiming, run_periodic

log = structlog.get_logger("compd.service.daemon")

#: Input history kept for starting a newly loaded model warm (s): hours, as the machine's time constants.
HISTORY_S = 8 * 3600.0


def build_drivers(config: Config, now: Callable[[], float]) -> dict[str, Driver]:
    """One driver per config entry; each type's module is imported here, not before."""
    return {
        name: load_driver_type(doc.type)(
            config.driver_settings[name], now=now, base_dir=config.base_dir
        )
        for name, doc in config.doc.drivers.items()
    }


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
        self.drivers = dict(drivers) if drivers is not None else build_drivers(config, clock.now)
        try:
            saved = load_state(config.state_dir)
        except StateError as exc:
            log.warning("saved state ignored", reason=str(exc))
            saved = None
        decision = resume_decision(
            saved,
            slot.sha256,
            slot.compiled,
            now_unix,
            doc.state.resume_max_age_s,
            real_now_unix_s=time.time(),
            time_scale=getattr(clock, "time_scale", 1.0),
            max_offsets_um={axis: out.max_offset_um for axis, out in doc.outputs.items()},
        )
        log.info(
            "model",
            name=slot.compiled.name,
            sha256=slot.sha256,
            path=slot.model_file.path,
            resume=decision.resume,
            reason=decision.reason,
        )
        self.resumed = decision.resume
        offsets = dict(saved.offsets_um) if saved is not None and decision.resume else {}
        safety = {
            axis: AxisSafety(
                AxisLimits(out.max_offset_um, out.max_rate_um_per_s),
                doc.period_s,
                on_fault=FaultMode(doc.safety.on_fault),
                fault_ramp_after_s=doc.safety.fault_ramp_after_s,
                offset_um=offsets.get(axis, 0.0),
            )
            for axis, out in doc.outputs.items()
        }
        self.links = {
            name: DriverLink(
                name,
                self.drivers[name],
                clock,
                timeout_s=d.timeout_s,
                backoff_min_s=d.reconnect_min_s,
                backoff_max_s=d.reconnect_max_s,
            )
            for name, d in doc.drivers.items()
        }
        status = doc.status
        self.loader = ModelLoader(config, clock.wall)
        self.compensator = Compensator(
            signals=[
                SignalPoint(name, s.driver, s.address, s.scale, s.offset, s.type)
                for name, s in doc.signals.items()
            ],
            monitors={
                name: SignalMonitor(name, Checks(**s.checks.model_dump()))
                for name, s in doc.signals.items()
            },
            axes=[
                AxisPoint(
                    axis,
                    o.model_output,
                    o.driver,
                    o.address,
                    float(o.sign),
                    o.encoding.scale,
                    config.whole_counts.get(axis, o.encoding.type == "int"),
                    readback=config.readback.get(axis, False),
                )
                for axis, o in doc.outputs.items()
            ],
            safety=safety,
            links=self.links,
            model=slot,
            status=StatusPoint(
                status.driver,
                status.status_address,
                status.heartbeat_address,
                mismatch_bit=config.mismatch_bit is not None,
                model_fault_bit=config.model_fault_bit is not None,
            )
            if status
            else None,
            blend_s=doc.blend_s,
            wall_at=clock.wall_at,
            initial_state=saved.model_state if saved is not None and decision.resume else None,
            history_ticks=round(HISTORY_S / doc.period_s),
            schedule=GainScheduler(doc.gain_schedule.gain_table()) if doc.gain_schedule else None,
            on_model_failure=self.loader.failed,
        )
        self.compensator.fallback = fallback
        if saved is not None and decision.resume:
            self.compensator.heartbeat = saved.ticks % HEARTBEAT_MODULO
        self.timing = TickTiming()
        self.stop_event = asyncio.Event()
        self.started_unix_s = now_unix
        self._control = (
            ControlServer(
                config.control_socket,
                {"status": self._status, "load": self._load},
                access={"load": Access(*doc.load_access.ids())},
            )
            if control
            else None
        )
        self.recorder = (
            Recorder(
                config.recorder_dir,
                max_file_bytes=doc.recorder.max_file_bytes,
                max_file_age_s=doc.recorder.max_file_age_s,
                max_total_bytes=doc.recorder.max_total_bytes,
            )
            if config.recorder_dir is not None
            else None
        )
        self._recorder_fault = FaultLog(log)
        self._save_fault = FaultLog(log)  # saves fail every save_every_ticks: log once
        self._saving: asyncio.Future[None] | None = None

    async def run(self, *, duration_s: float | None = None) -> TickTiming:
        """Run until :meth:`stop` (or ``duration_s`` of clock time); then shut down cleanly."""
        # The control socket first: a second daemon on the same socket is refused
        # here, before it opens a driver, let alone writes to the machine.
        if self._control is not None:
            self.config.control_socket.parent.mkdir(parents=True, exist_ok=True)
            await self._control.start()
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

    def snapshot(self) -> SavedState | None:
        """What :meth:`save_state` writes: the active model's state and the offsets, now."""
        slot = self.compensator.active
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
        record = await self.compensator.tick(t_s)
        ticks = self.compensator.counters.ticks
        if ticks == 1:
            self.notifier.ready(f"compensating with {self.compensator.active.compiled.name}")
        # systemd's watchdog restarts a daemon whose loop has stalled or hangs in I/O: ping
        # only for a tick that finished within its period, so a loop that can no longer keep
        # its deadlines stops pinging. A machine that is merely unreachable (PLC off at
        # night) still gets healthy ticks: freezing the offsets is the right behaviour
        # there, and restarting would not help.
        if self.clock.now() - started_s < self.config.doc.period_s:
            self.notifier.watchdog()
        if ticks % self.config.doc.live_every_ticks == 0:
            self.notifier.status(_summary(record))
        if self.recorder is not None:
            self._record(record)
        if ticks % self.config.doc.state.save_every_ticks == 0:
            self._save_in_background()
        if self.on_tick is not None:
            self.on_tick(record)

    def _record(self, record: TickRecord) -> None:
        assert self.recorder is not None
        row: dict[str, float | int | str] = {"t_s": record.t_s}
        row |= record.values
        row |= {f"health.{k}": int(v) for k, v in record.health.items()}
        row |= {f"model.{k}": v for k, v in record.model_outputs.items()}
        row |= {f"model.{k.replace('/', '.')}": v for k, v in record.contributions.items()}
        # What the devices acknowledged (NaN: not written), and what they held before the write.
        row |= {f"offset.{k}_um": v for k, v in record.acknowledged_um.items()}
        row |= {f"readback.{k}_um": v for k, v in record.readback_um.items()}
        row |= {f"gain.{k}": v for k, v in record.gains.items()}
        row |= {"status": record.status, "heartbeat": record.heartbeat}
        try:
            self.recorder.record(row, at_s=record.wall_unix_s)
        except RecorderError as exc:
            self._recorder_fault.failed("recorder failed", error=str(exc))
        else:
            self._recorder_fault.cleared("recorder works again")

    async def _shutdown(self) -> None:
        self.notifier.stopping("saving state")
        if self._saving is not None:
            await self._saving
        self.save_state()
        await self.compensator.write_stopped()
        await asyncio.gather(*(link.close() for link in self.links.values()))
        if self._control is not None:
            await self._control.close()
        if self.recorder is not None:
            try:
                self.recorder.close()
            except RecorderError as exc:
                log.error("recorder close failed", error=str(exc))
        log.info("stopped", ticks=self.compensator.counters.ticks, overruns=self.timing.overruns)

    async def _load(self, message: dict[str, Any]) -> dict[str, Any]:
        slot = await self.loader.accept(message)
        self.compensator.load(slot)
        path = slot.model_file.path
        log.info("model loading", name=slot.compiled.name, sha256=slot.sha256, path=path)
        return {
            "model": slot.compiled.name,
            "sha256": slot.sha256,
            "installed": path,
            "blend_s": self.config.doc.blend_s,
        }

    async def _status(self, message: dict[str, Any]) -> dict[str, Any]:
        return self.status()

    def status(self) -> dict[str, Any]:
        """A JSON-able snapshot: model, last tick, inputs and health, offsets, counters."""
        comp = self.compensator
        slot, last = comp.active, comp.last
        counters = comp.counters
        return {
            "model": {
                "name": slot.compiled.name,
                "sha256": slot.sha256,
                "path": slot.model_file.path,
                "loaded": _iso(slot.loaded_at_unix_s),
                "started": slot.runner is not None,
                "pending": comp.pending.compiled.name if comp.pending else None,
                "blending_from": comp.previous.compiled.name if comp.previous else None,
                "fault": comp.model_fault,
            },
            "gain_schedule": comp.schedule.status() if comp.schedule is not None else None,
            "resumed": self.resumed,
            "started": _iso(self.started_unix_s),
            "last_tick": None if last is None else _iso(last.wall_unix_s),
            "status_word": None if last is None else last.status,
            "heartbeat": comp.heartbeat,
            "offsets_um": {a: s.offset_um for a, s in comp.safety.items()},
            # What the PLC holds as far as compd knows (read back, else acknowledged).
            "offsets_held_um": comp.held.known_um(),
            "targets_um": {} if last is None else last.targets_um,
            "inputs": {
                name: {
                    "value": _finite(m.reading.value),
                    "health": m.reading.health.name.lower(),
                    "reason": m.reading.reason,
                }
                for name, m in comp.monitors.items()
            },
            "drivers": {name: ("up" if link.up else "down") for name, link in self.links.items()},
            "counters": {
                "ticks": counters.ticks,
                "overruns": self.timing.overruns,
                "max_lateness_ms": round(self.timing.max_lateness_s * 1e3, 3),
                "signal_faults": counters.signal_faults,
                "driver_faults": sum(link.faults for link in self.links.values()),
                "reconnects": sum(link.reconnects for link in self.links.values()),
                "write_failures": counters.write_failures,
                "model_loads": counters.model_loads,
                "offset_mismatches": counters.offset_mismatches,
                "model_failures": counters.model_failures,
            },
        }


def _summary(record: TickRecord) -> str:
    """One line for ``systemctl status``: offsets and the status level."""
    offsets = ", ".join(f"{axis} {value:+.2f} um" for axis, value in record.offsets_um.items())
    return f"{offsets}; status word {record.status}"


def _iso(unix_s: float) -> str:
    return datetime.fromtimestamp(unix_s, UTC).isoformat(timespec="seconds")


def _finite(value: float) -> float | None:
    return value if math.isfinite(value) else None
