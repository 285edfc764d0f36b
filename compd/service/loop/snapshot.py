"""One tick, as everything outside the loop sees it: an immutable snapshot.

The loop core (schedule, read, monitor, step, safety, write, read back)
produces one :class:`TickSnapshot` per tick and hands the same object to every
subscriber (:mod:`compd.service.loop.subscribers`): the recorder, telemetry,
the metrics and page, the systemd notifier, the state saver, the soak's
witness, the probe learner. None of them re-derives what another already
knows: the counters, the running model and the tick's timing are taken once,
here, and ``compd status``, telemetry and ``/metrics`` read the same ones.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType

from compd.service.loop.compensator import TickRecord


@dataclass(frozen=True, slots=True)
class ModelId:
    """The model that ran this tick: its name and the sha256 of its file."""

    name: str
    sha256: str


@dataclass(frozen=True, slots=True)
class TickSnapshot:
    """What one tick saw and did, with the service's counters and the tick's timing after it.

    ``record`` carries the inputs with their health, the model's outputs and
    contributions, the offsets asked, acknowledged and read back, and the
    status word. ``counters`` is read-only: the one set of counters that
    ``compd status``, telemetry and the metrics give.
    """

    record: TickRecord
    #: Ticks run so far, this one included (1: the first tick of this run).
    ticks: int
    counters: Mapping[str, int]
    #: None: a data logger (no model).
    model: ModelId | None
    #: How late the tick started after its deadline (s), and the CPU it took (s; NaN where no
    #: subscriber reads it: :attr:`~compd.service.loop.subscribers.Subscribers.read_cpu`).
    lateness_s: float
    cpu_s: float
    #: When the tick started, ``time.perf_counter()`` time (s).
    started_real_s: float
    #: The tick finished within its period (on the loop's clock): what the watchdog pings for.
    on_time: bool

    @property
    def first(self) -> bool:
        """The first tick of this run: the service is ready."""
        return self.ticks == 1

    @staticmethod
    def frozen(counters: dict[str, int]) -> Mapping[str, int]:
        """``counters``, a dict no one else keeps, as a read-only mapping (a subscriber cannot
        change what the next one reads)."""
        return MappingProxyType(counters)
