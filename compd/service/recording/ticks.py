"""The recorder as the loop's subscriber: one row per tick, a failing disk a fault episode."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import structlog

from compd.errors import RecorderError
from compd.faultlog import FaultLog
from compd.service.loop.compensator import TickRecord
from compd.service.loop.snapshot import ModelId, TickSnapshot
from compd.service.recording.parquet import ParquetRecorder
from compd.service.recording.recorder import Recorder

log = structlog.get_logger("compd.service.recording")


def tick_row(snapshot: TickSnapshot) -> dict[str, float | int | str]:
    """The recorded row of one tick: what each signal read and what was used, model, offsets, status."""
    return tick_row_of(snapshot.record)


def tick_row_of(record: TickRecord) -> dict[str, float | int | str]:
    """:func:`tick_row` of a tick's record."""
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


class RowLayout:
    """:func:`tick_row` as columns and values, the column names made once per set of keys.

    A tick's record has the same keys tick after tick (until another model
    runs): naming ~50 columns and building the dict each tick was most of the
    row's cost, with cold caches. The values are in :func:`tick_row`'s order.
    """

    def __init__(self) -> None:
        self._keys: tuple[tuple[str, ...], ...] = ()
        self._columns: tuple[str, ...] | None = ()

    def row(self, record: TickRecord) -> tuple[tuple[str, ...], list[float | int | str]]:
        """The columns (the same tuple while the keys stay) and the values of ``record``'s row."""
        parts = _parts(record)
        values: list[float | int | str] = [record.t_s]
        values += parts[0].values()
        values += parts[1].values()
        values += map(int, parts[2].values())  # the health, as a number
        for part in parts[3:]:
            values += part.values()
        values += (record.status, record.heartbeat)
        keys = tuple(map(tuple, parts))
        if keys != self._keys:
            names = [name(key) for name, part in zip(_NAMES, keys, strict=True) for key in part]
            columns = ("t_s", *names, "status", "heartbeat")
            self._keys = keys
            self._columns = columns if len(set(columns)) == len(columns) else None
        if self._columns is None:  # names that clash: the dict keeps the last, as tick_row's
            row = tick_row_of(record)
            return tuple(row), list(row.values())
        return self._columns, values


def _parts(record: TickRecord) -> list[Mapping[str, Any]]:
    """The record's mappings in :func:`tick_row`'s order, each named by :data:`_NAMES`."""
    return [
        record.values,
        record.read,
        record.health,
        record.model_outputs,
        record.contributions,
        record.acknowledged_um,
        record.readback_um,
        record.gains,
        record.probe_adjustments_um,
        record.probe_innovations_um,
    ]


_NAMES: tuple[Callable[[str], str], ...] = (
    lambda k: k,
    lambda k: f"read.{k}",
    lambda k: f"health.{k}",
    lambda k: f"model.{k}",
    lambda k: f"model.{k.replace('/', '.')}",
    lambda k: f"offset.{k}_um",
    lambda k: f"readback.{k}_um",
    lambda k: f"gain.{k}",
    lambda k: f"probe.{k}.adjustment_um",
    lambda k: f"probe.{k}.innovation_um",
)


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
        self._layout = RowLayout()
        #: The model the files were last told of (the daemon keeps one ModelId per model).
        self._model: ModelId | None = None

    def on_tick(self, snapshot: TickSnapshot) -> None:
        try:
            model = snapshot.model
            if model is not None and model is not self._model:  # a data logger names no model
                self.recorder.set_model(model.name, model.sha256)
                self._model = model
            if self.extra_columns is None:
                columns, values = self._layout.row(snapshot.record)
                self.recorder.record_values(columns, values, at_s=snapshot.record.wall_unix_s)
            else:
                row = tick_row(snapshot)
                row |= self.extra_columns()
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
