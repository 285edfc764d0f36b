"""The last hour of ticks and the last faults, in memory, for the status page (``GET /history.json``).

A ring buffer of :data:`CAPACITY` rows -- one per second of the clock at
most, so an hour whatever the period -- holding each stored tick's time,
offsets per axis, inputs and status word. Appending is one row copy into a
preallocated numpy array (a few microseconds in the tick); the page asks for
at most ``points`` rows, every n-th, so its answer stays small however long
the buffer. Nothing is written to disk: the recorder's files are the record,
this is only what a person glancing at the page wants to see.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from compd.service.loop.compensator import Compensator, TickRecord
from compd.service.loop.links import DriverLink
from compd.service.loop.probemessages import ProbeTaken
from compd.service.loop.signals import Health

#: Rows kept: an hour at one row per second.
CAPACITY = 3600
#: The least clock time between two rows kept (s): a faster loop keeps every n-th tick.
MIN_SPACING_S = 1.0
#: Fault starts the page lists.
MAX_FAULTS = 20


class TickHistory:
    """The last :data:`CAPACITY` rows of (time, offsets, inputs, status word), decimated to >= 1 s apart."""

    def __init__(
        self,
        axes: Sequence[str],
        signals: Sequence[str],
        period_s: float,
        *,
        capacity: int = CAPACITY,
    ) -> None:
        self.axes = list(axes)
        self.signals = list(signals)
        #: Ticks per row kept: 1 at a period of 1 s or more.
        self.every = max(1, math.ceil(MIN_SPACING_S / period_s - 1e-9))
        self.capacity = capacity
        self._rows = np.full((capacity, 2 + len(self.axes) + len(self.signals)), np.nan)
        self._count = 0  # rows ever stored
        self._ticks = 0

    def __len__(self) -> int:
        return min(self._count, self.capacity)

    def append(self, record: TickRecord) -> None:
        """Keep ``record`` if it is the n-th tick since the last kept (see :attr:`every`)."""
        self._ticks += 1
        if (self._ticks - 1) % self.every:
            return
        row = self._rows[self._count % self.capacity]
        row[0] = record.wall_unix_s
        row[1] = record.status
        k = 2
        for axis in self.axes:
            row[k] = record.offsets_um.get(axis, math.nan)
            k += 1
        for signal in self.signals:
            row[k] = record.values.get(signal, math.nan)
            k += 1
        self._count += 1

    def snapshot(self, points: int = 720) -> dict[str, Any]:
        """Columns of at most ``points`` rows, oldest first, every n-th (the newest always in); NaN as None."""
        n = len(self)
        start = self._count - n
        order = (np.arange(start, self._count) % self.capacity) if n else np.arange(0)
        step = max(1, math.ceil(n / max(1, points)))
        picked = self._rows[order[::-1][::step][::-1]]  # counted from the newest row back
        columns = [_json_floats(picked[:, k]) for k in range(picked.shape[1])]
        width = len(self.axes)
        return {
            "t_unix_s": columns[0],
            "status_word": [None if v is None else int(v) for v in columns[1]],
            "offsets_um": dict(zip(self.axes, columns[2 : 2 + width], strict=True)),
            "inputs": dict(zip(self.signals, columns[2 + width :], strict=True)),
            "every_ticks": self.every * step,
        }


def _json_floats(column: np.ndarray) -> list[float | None]:
    """The column as a JSON-able list: NaN and inf (no value) as None."""
    values: list[float] = column.tolist()
    return [v if math.isfinite(v) else None for v in values]


@dataclass(frozen=True)
class FaultEvent:
    """One fault as the page lists it: when (UTC epoch s), its kind, what it concerns, and why."""

    at_unix_s: float
    kind: str
    source: str
    message: str


class RecentFaults:
    """The last :data:`MAX_FAULTS` fault starts, newest first, found by comparing each tick with the last.

    Kinds as in ``compd_faults_total``: ``signal`` (an input turned held or
    faulted), ``driver`` (a link went down), ``write`` (a tick's writes
    failed), ``model`` (the model faulted), ``readback_mismatch``,
    ``offset_out_of_clamp``, ``envelope`` (an axis's target at the clamp or beyond
    its calibration for ``envelope_after_s``). Only the
    start of an episode is listed, so a fault lasting an hour is one line.
    Model loads (a model switched in while running) and probes are kept apart,
    in :attr:`loads` and :attr:`probes`, for the page's charts to mark beside the faults.
    """

    def __init__(self, maxlen: int = MAX_FAULTS) -> None:
        self.events: deque[FaultEvent] = deque(maxlen=maxlen)
        #: The last model loads, newest first, as events of kind ``model_load``.
        self.loads: deque[FaultEvent] = deque(maxlen=maxlen)
        #: The last probes, newest first, as events of kind ``probe`` at their touch.
        self.probes: deque[FaultEvent] = deque(maxlen=maxlen)
        self._model_loads = 0
        self._health: dict[str, Health] = {}
        self._up: dict[str, bool] = {}
        self._model_fault: str | None = None
        self._written = True
        self._mismatches = 0
        self._out_of_clamp = 0
        self._envelope_faulted: set[str] = set()

    def update(
        self, record: TickRecord, comp: Compensator, links: Mapping[str, DriverLink]
    ) -> None:
        """Compare this tick with the last; list what started failing."""
        at = record.wall_unix_s
        # Inputs that turn bad at one tick for one reason (a driver down: all go stale) are one line.
        started: dict[str, list[str]] = {}
        for name, health in record.health.items():
            if health is not Health.OK and health is not self._health.get(name, Health.OK):
                reason = record.reasons.get(name, "")
                started.setdefault(f"{health.name.lower()}: {reason}".rstrip(": "), []).append(name)
            self._health[name] = health
        for message, names in started.items():
            self._add(at, "signal", ", ".join(names), message)
        for name, link in links.items():
            if not link.up and self._up.get(name, True):
                self._add(at, "driver", name, "link down; reconnecting")
            self._up[name] = link.up
        if not record.written and self._written and all(link.up for link in links.values()):
            self._add(at, "write", "outputs", "a write was not acknowledged")
        self._written = record.written
        fault = comp.model_fault
        if fault is not None and fault != self._model_fault:
            self._add(at, "model", comp.active.compiled.name, fault)
        self._model_fault = fault
        mismatches = comp.counters.offset_mismatches
        if mismatches > self._mismatches:
            self._add(
                at, "readback_mismatch", "offsets", "an offset read back was not what compd wrote"
            )
        self._mismatches = mismatches
        out_of_clamp = comp.counters.offsets_out_of_clamp
        if out_of_clamp > self._out_of_clamp:
            self._add(
                at,
                "offset_out_of_clamp",
                ", ".join(sorted(comp.held.out_of_clamp)) or "offsets",
                "an offset read back outside its clamp or not finite was replaced, not followed",
            )
        self._out_of_clamp = out_of_clamp
        faulted = {axis for axis, stage in comp.safety.items() if stage.watch.faulted}
        for axis in sorted(faulted - self._envelope_faulted):
            self._add(
                at, "envelope", axis, record.outside_envelope.get(axis, "outside its envelope")
            )
        self._envelope_faulted = faulted
        loads = comp.counters.model_loads
        if loads > self._model_loads and comp.running is not None:
            self.loads.appendleft(
                FaultEvent(at, "model_load", comp.running.compiled.name, "model switched in")
            )
        self._model_loads = loads
        for taken in record.probes:
            self.probes.appendleft(_probe_event(taken))

    def _add(self, at_unix_s: float, kind: str, source: str, message: str) -> None:
        self.events.appendleft(FaultEvent(at_unix_s, kind, source, message))

    def as_json(self) -> list[dict[str, Any]]:
        return [asdict(event) for event in self.events]

    def loads_json(self) -> list[dict[str, Any]]:
        return [asdict(event) for event in self.loads]

    def probes_json(self) -> list[dict[str, Any]]:
        return [asdict(event) for event in self.probes]


def _probe_event(taken: ProbeTaken) -> FaultEvent:
    """A probe as the chart marks it: its result, and what it measured against the prediction."""
    details = taken.event_details()
    if taken.refused is not None:
        said = f"refused: {taken.refused}"
    else:
        step = taken.steps[-1]
        said = (
            f"{taken.result}: measured {taken.request.measured_um:+.2f} um ({taken.request.measures}),"
            f" innovation {step.innovation_before_um:+.2f} um, after the update "
            f"{step.innovation_after_um:+.2f} um"
        )
    return FaultEvent(details["touched_at_unix_s"], "probe", details["axis"], said)
