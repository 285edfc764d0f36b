"""The recorder as the loop's subscriber: one row per tick, a failing disk a fault episode."""

from __future__ import annotations

from collections.abc import Callable, Mapping

import structlog

from compd.errors import RecorderError
from compd.faultlog import FaultLog
from compd.service.loop.snapshot import TickSnapshot
from compd.service.recording.parquet import ParquetRecorder
from compd.service.recording.recorder import Recorder

log = structlog.get_logger("compd.service.recording")


def tick_row(snapshot: TickSnapshot) -> dict[str, float | int | str]:
    """The recorded row of one tick: what each signal read and what was used, model, offsets, status."""
    record = snapshot.record
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
    # What the probes taught (added to each output), and a probe's innovation on its tick.
    row |= {f"probe.{k}.adjustment_um": v for k, v in record.probe_adjustments_um.items()}
    row |= {f"probe.{k}.innovation_um": v for k, v in record.probe_innovations_um.items()}
    row |= {"status": record.status, "heartbeat": record.heartbeat}
    return row


class RecordingTicks:
    """Writes each tick's row; a recorder that cannot write is one ERROR line, then one when it can again."""

    name = "recorder"

    def __init__(self, recorder: Recorder | ParquetRecorder) -> None:
        self.recorder = recorder
        #: The recorder's fault episodes: ``active`` while it cannot write, ``episodes`` so far.
        self.fault = FaultLog(log)
        #: Columns added to every row, asked for at the tick (the same names each tick): the
        #: simulated machine's truth (``sim.residue.<axis>_um``, :mod:`compd.sim.plc.run`), which
        #: the service itself cannot know. None: the row as the tick made it.
        self.extra_columns: Callable[[], Mapping[str, float]] | None = None

    def on_tick(self, snapshot: TickSnapshot) -> None:
        row = tick_row(snapshot)
        if self.extra_columns is not None:
            row |= self.extra_columns()
        try:
            if snapshot.model is not None:  # a data logger names no model
                self.recorder.set_model(snapshot.model.name, snapshot.model.sha256)
            self.recorder.record(row, at_s=snapshot.record.wall_unix_s)
        except RecorderError as exc:
            self.fault.failed("recorder failed", error=str(exc))
        else:
            if self.fault.active:  # once, at the end of the episode
                lost = self.recorder.take_lost_rows()
                self.fault.cleared("recorder works again", lost_rows=lost)

    async def end(self, *, killed: bool) -> None:
        """Close the open file (not when killed: SIGKILL leaves it as it is)."""
        if killed:
            return
        try:
            self.recorder.close()
        except RecorderError as exc:
            log.error("recorder close failed", error=str(exc))
