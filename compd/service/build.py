"""The builder: runtime objects from the config's documents, and the loop's subscribers in order.

Config documents (:mod:`compd.service.config`) describe; this module builds
what has a life of its own from them: the recorder, the MQTT publisher, the
HTTP server, and the list of tick subscribers the daemon registers. A new
subscriber is a class and a line in :func:`tick_subscribers`. Each optional
room's libraries (paho, aiohttp, pyarrow) are imported only for a config
that asks for it.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from compd.faultlog import EventSink, FaultLog
from compd.service.config.docs import RecorderDoc
from compd.service.config.fleetdoc import HttpDoc, TelemetryDoc
from compd.service.config.loading import Config
from compd.service.config.writepoints import probe_axes
from compd.service.identity import column_units, recording_metadata
from compd.service.loop.points import SignalPoint
from compd.service.loop.probemessages import ProbeRegisters, ProbeSetup
from compd.service.loop.subscribers import Subscriber
from compd.service.notify import SystemdNotifier, SystemdTicks
from compd.service.recording.marks import Units
from compd.service.recording.parquet import DEFAULT_FLUSH_EVERY_ROWS, ParquetRecorder
from compd.service.recording.recorder import Recorder
from compd.service.recording.ticks import RecordingTicks
from compd.service.store.saver import StateSaver
from compd.service.store.state import MODELS_DIR, SavedState

if TYPE_CHECKING:
    from compd.service.fleet.telemetry import Telemetry
    from compd.service.http.server import StatusServer
    from compd.service.http.view import ServiceView
    from compd.service.loop.probing import ProbeLearning
    from compd.service.store.probes import ProbeKeeper


class Reporter(Protocol):
    """What tells an event sink of its fault episodes and events (a driver link, the compensator)."""

    def report_to(self, sink: EventSink) -> None: ...


def recorder(
    doc: RecorderDoc,
    directory: Path,
    metadata: Mapping[str, str] | None = None,
    units: Units | None = None,
) -> Recorder | ParquetRecorder:
    """The recorder writing into ``directory`` (resolved by :mod:`compd.service.config.paths`).

    ``metadata`` (machine id, compd version, config path) goes into every
    file, with each column's unit as ``units`` names it.
    """
    # pyarrow is imported by the Parquet recorder's first write, so only when configured.
    kind = ParquetRecorder if doc.format == "parquet" else Recorder
    default_rows = DEFAULT_FLUSH_EVERY_ROWS if doc.format == "parquet" else 1
    made = kind(
        directory,
        max_file_bytes=doc.max_file_bytes,
        max_file_age_s=doc.max_file_age_s,
        max_total_bytes=doc.max_total_bytes,
        flush_every_rows=doc.flush_every_rows or default_rows,
        metadata=metadata,
    )
    made.run.units = units
    return made


def telemetry(
    doc: TelemetryDoc,
    base_dir: Path,
    *,
    identity: Callable[[], dict[str, Any]],
    wall: Callable[[], float],
    probes: Callable[[], dict[str, Any] | None] = lambda: None,
) -> Telemetry:
    """The publisher, not yet connected; paho is imported here, only for a config that asks."""
    from compd.service.fleet.claim import Instance
    from compd.service.fleet.mqttlink import Topics, broker
    from compd.service.fleet.telemetry import Telemetry

    # Each process its own client id: with one, two daemons would throw each other off the
    # broker before either could see the other's birth (compd.service.fleet.claim).
    instance = Instance.this_process()
    return Telemetry(
        broker(doc, base_dir, doc.client_id or f"compd-{doc.machine_id}-{instance.id[:8]}"),
        Topics(doc.topic_prefix, doc.machine_id),
        instance=instance,
        qos=doc.qos,
        every_ticks=doc.every_ticks,
        queue_size=doc.queue_size,
        identity=identity,
        wall=wall,
        probes=probes,
    )


def probes_now(view: ServiceView) -> dict[str, Any] | None:
    """Per probed axis what the probes say now (None: the config probes nothing), for telemetry."""
    probing = view.probing
    return None if probing is None else probing.status(view.clock_wall())["axes"]


def fleet_wiring(
    publisher: Telemetry,
    config: Config,
    *,
    reporters: Sequence[Reporter],
    faults: Sequence[FaultLog],
    load_model: Callable[[dict[str, Any]], Awaitable[dict[str, Any]]],
    take_probe: Callable[[dict[str, Any]], Awaitable[dict[str, Any]]] | None,
) -> None:
    """Telemetry hears every fault episode and event, and answers the fleet's commands.

    ``reporters`` (links, the compensator) report to it, ``faults`` (the state
    saver's, the recorder's) episodes go to it; with ``accept_models`` it takes
    roll-outs (``load_model``, replays refused across restarts, a machine back
    catching up with its desired model), with probes a CMM station's results.
    """
    from compd.service.fleet.remoteload import COMMAND, MAX_PAYLOAD_BYTES, RemoteLoads
    from compd.service.fleet.remoteprobe import COMMAND as PROBE_COMMAND
    from compd.service.fleet.remoteprobe import MAX_PAYLOAD_BYTES as PROBE_MAX_BYTES
    from compd.service.fleet.remoteprobe import RemoteProbes
    from compd.service.fleet.seenrequests import FILE as SEEN_FILE
    from compd.service.fleet.seenrequests import SeenRequests

    sink = publisher.event
    for reporter in reporters:
        reporter.report_to(sink)
    for fault in faults:
        fault.sink = sink
    doc = config.doc.telemetry
    if doc is not None and doc.accept_models:
        seen = SeenRequests(config.state_dir / SEEN_FILE)  # replays refused across restarts
        models = config.state_dir / MODELS_DIR
        remote = RemoteLoads(
            load_model,
            publisher.reply,
            sink,
            seen=seen,
            installed=lambda sha256: (models / f"{sha256}.yaml").is_file(),
        )
        publisher.listen(COMMAND, remote.handle, max_bytes=MAX_PAYLOAD_BYTES)
        publisher.take_desired(remote.take_desired)  # a machine back catches up
    if take_probe is not None:  # a CMM station's or a gauge PC's results
        from compd.service.fleet.remoteprobe import FILE as PROBE_IDS
        from compd.service.fleet.remoteprobe import KEEP_S as PROBE_IDS_KEPT_S

        seen_probes = SeenRequests(config.state_dir / PROBE_IDS, window_s=PROBE_IDS_KEPT_S)
        probes = RemoteProbes(take_probe, publisher.reply, sink, seen=seen_probes)
        publisher.listen(PROBE_COMMAND, probes.handle, max_bytes=PROBE_MAX_BYTES)


def http_server(doc: HttpDoc, service: ServiceView) -> StatusServer:
    """The server for ``service`` (:class:`compd.service.http.server.StatusServer`), not yet started.

    Its module (aiohttp, prometheus_client) is imported here: a config without
    ``http`` loads neither.
    """
    from compd.service.http.server import StatusServer

    return StatusServer(
        service,
        host=doc.listen,
        port=doc.port,
        max_connections=doc.max_connections,
        idle_timeout_s=doc.idle_timeout_s,
    )


def probe_keeper(config: Config, *, background: bool, real_time: bool = True) -> ProbeKeeper | None:
    """The probe log and learned parameters' keeper, where the config has probes."""
    doc = config.doc
    if doc.probes is None or not doc.probes.enabled or not doc.outputs:
        return None
    from compd.service.store.probes import ProbeKeeper  # the update's numerics: only with probes

    return ProbeKeeper(config.state_dir, background=background, real_time=real_time)


def probe_learning(config: Config, keeper: ProbeKeeper | None) -> ProbeLearning | None:
    """The probe updates the config's ``probes`` section asks for (None: off, or a data logger)."""
    doc = config.doc
    probes = doc.probes
    if probes is None or not probes.enabled or not doc.outputs:
        return None
    setup = ProbeSetup(
        measures=probes.measures,
        every_h=probes.every_h,
        overrides=probes.overrides(),
        axes=tuple(probes.axes),
        min_gap_s=probes.min_gap_s,
    )
    registers = [
        ProbeRegisters(
            axis=axis,
            driver=reg.driver,
            value=SignalPoint(
                f"probe.{axis}.value_um", reg.driver, reg.value_address, reg.value_scale
            ),
            counter=SignalPoint(f"probe.{axis}.count", reg.driver, reg.counter_address, kind="int"),
            echo_address=reg.echo_address,
            echo=SignalPoint(f"probe.{axis}.echo", reg.driver, reg.echo_address, kind="int"),
            touched_at=(
                None
                if reg.touched_at_address is None
                else SignalPoint(
                    f"probe.{axis}.touched_at_unix_s", reg.driver, reg.touched_at_address
                )
            ),
            status_address=reg.status_address,
        )
        for axis, reg in probe_axes(doc)
    ]
    from compd.service.loop.probing import ProbeLearning  # the update's numerics: only with probes

    return ProbeLearning(
        setup,
        config.axis_points(),
        registers,
        restore=None if keeper is None else keeper.restore,
    )


@dataclass
class Subscribed:
    """The loop's subscribers built for one service; the daemon keeps handles for their lifecycles."""

    systemd: SystemdTicks
    recording: RecordingTicks | None
    saver: StateSaver
    telemetry: Telemetry | None
    http: StatusServer | None
    probes: ProbeKeeper | None = None

    def in_order(self) -> list[Subscriber]:
        """The order each tick is told in, each begins and ends: systemd's watchdog first; the state
        saved before telemetry's last message; the page listening before the broker is called."""
        return [
            s
            for s in (
                self.systemd,
                self.recording,
                self.saver,
                self.probes,
                self.http,
                self.telemetry,
            )
            if s is not None
        ]


def tick_subscribers(
    config: Config,
    view: ServiceView,
    *,
    notifier: SystemdNotifier,
    saved_state: Callable[[], SavedState | None],
    background_saves: bool,
    identity: Callable[[], dict[str, Any]],
    wall: Callable[[], float],
    probe_keeper: ProbeKeeper | None = None,
) -> Subscribed:
    """Everything that follows the loop, as ``config`` asks for it."""
    doc = config.doc
    recording = (
        RecordingTicks(
            recorder(
                doc.recorder, config.recorder_dir, recording_metadata(config), column_units(config)
            )
        )
        if config.recorder_dir is not None
        else None
    )
    saver = StateSaver(
        config.state_dir,
        saved_state,
        every_ticks=doc.state.save_every_ticks,
        background=background_saves,
    )
    return Subscribed(
        systemd=SystemdTicks(
            notifier,
            status_every_ticks=doc.live_every_ticks,
            notes=view.not_assured,
        ),
        recording=recording,
        saver=saver,
        telemetry=(
            telemetry(
                doc.telemetry,
                config.base_dir,
                identity=identity,
                wall=wall,
                probes=lambda: probes_now(view),
            )
            if doc.telemetry is not None
            else None
        ),
        http=http_server(doc.http, view) if doc.http is not None and doc.http.enabled else None,
        probes=probe_keeper,
    )
