"""What the metrics and the page read of a running service: a narrow view, not the daemon itself.

The HTTP room sits below the daemon: it is handed any object with these
attributes (the daemon's :class:`~compd.service.daemon.Service` is one), so
nothing here imports the daemon and a test can serve a view of its own.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any, Protocol

from compd.faultlog import FaultLog
from compd.service.config.loading import Config
from compd.service.loop.clock import Clock
from compd.service.loop.compensator import Compensator
from compd.service.loop.links import DriverLink
from compd.service.loop.snapshot import TickSnapshot
from compd.service.loop.ticks import TickTiming
from compd.service.store.saver import StateSaver

if TYPE_CHECKING:
    from compd.service.loop.probing import ProbeLearning


class MqttCounters(Protocol):
    """The MQTT link's counters the metrics give."""

    @property
    def connected(self) -> bool: ...
    @property
    def connections(self) -> int: ...
    @property
    def published(self) -> int: ...
    @property
    def acknowledged(self) -> int: ...
    @property
    def dropped(self) -> int: ...


class TelemetryView(Protocol):
    """The telemetry publisher as the metrics see it."""

    @property
    def counters(self) -> MqttCounters: ...
    @property
    def rival(self) -> object | None: ...


class ServiceView(Protocol):
    """The running service as the metrics and the page read it, between ticks."""

    @property
    def config(self) -> Config: ...
    @property
    def compensator(self) -> Compensator: ...
    @property
    def links(self) -> Mapping[str, DriverLink]: ...
    @property
    def timing(self) -> TickTiming: ...
    @property
    def clock(self) -> Clock: ...
    @property
    def started_unix_s(self) -> float: ...
    @property
    def telemetry(self) -> TelemetryView | None: ...
    @property
    def saver(self) -> StateSaver | None:
        """The state saver: whether saves fail, and why; None while the service is built."""

    @property
    def recorder_fault(self) -> FaultLog | None:
        """The recorder's fault episodes; None: the service records nothing."""

    @property
    def last(self) -> TickSnapshot | None:
        """The last tick's snapshot; None before the first."""

    @property
    def probing(self) -> ProbeLearning | None:
        """Probe updates (config ``probes``); None: off."""

    def clock_wall(self) -> float:
        """The loop clock's wall time now (unix s)."""

    def not_assured(self) -> list[str]:
        """What is not well though compensation goes on (the state not saved, inputs not verifiable)."""

    def status(self) -> dict[str, Any]:
        """``compd status``'s answer."""
