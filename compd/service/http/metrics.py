"""Prometheus metrics of a running service, in its own registry, served at ``/metrics``.

Two kinds, chosen by what each costs the 1 Hz tick:

- what only the tick can see is *observed* in it, into histograms: how late
  each tick woke (``compd_tick_lateness_seconds``), the CPU it took
  (``compd_tick_cpu_seconds``, the loop thread's CPU time) and how long each
  driver's read or write took (``compd_driver_io_seconds{driver,operation}``,
  timed by :class:`~compd.service.loop.links.DriverLink`). An observation is a few
  microseconds.
- everything the service already counts or holds -- ticks, faults by kind,
  reconnects by driver, offsets by axis, the status word, the inputs, the
  model and the fit % its provenance records -- is *read at scrape time* by
  :class:`LiveCollector`, between ticks (the server runs on the service's
  event loop): the counters and the last tick's record from the last
  :class:`~compd.service.loop.snapshot.TickSnapshot` (what ``compd status`` and
  telemetry give), the links, offsets and inputs from the objects that hold
  them. It costs the tick nothing and can never drift from ``compd status``.

Each service has its own :class:`~prometheus_client.CollectorRegistry`, not
the process-wide default, so tests and tools that run several services in
one process keep their metrics apart; it holds the process's own
``process_*`` series too (:class:`~prometheus_client.ProcessCollector`).

Names follow Prometheus's conventions (https://prometheus.io/docs/practices/naming/):
base units (``compd_offset_meters``, ``compd_model_fit_ratio`` 0-1), one
metric per physical quantity (``compd_signal_celsius``,
``compd_signal_watts``: :mod:`compd.service.config.metricunits`), the status
word's bits as their own series (``compd_status_flag{flag}``), an info
metric (``compd_info{version,machine_id}``) and no ``_created`` series.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Mapping

from prometheus_client import (
    CollectorRegistry,
    Histogram,
    ProcessCollector,
    disable_created_metrics,
)
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily
from prometheus_client.exposition import choose_encoder
from prometheus_client.metrics_core import Metric
from prometheus_client.registry import Collector

from compd import __version__
from compd.model.verifiable import Unverifiable
from compd.service.config.metricunits import prometheus_unit
from compd.service.config.verifiable import UnverifiableCache
from compd.service.http.view import ServiceView
from compd.service.loop.safety import Flag

#: Offsets are kept in um; Prometheus's base unit is the meter.
M_PER_UM = 1e-6

#: Wake-up lateness and tick CPU, in s: from 50 us (a tick on time) to a whole period missed.
TICK_BUCKETS_S = (
    0.00005, 0.0001, 0.00025, 0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0,
)  # fmt: skip
#: One driver read or write, in s: a local socket's 100 us to a timed-out request.
IO_BUCKETS_S = (
    0.0001, 0.00025, 0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5,
)  # fmt: skip


class ServiceMetrics:
    """The registry of one service: its histograms, observed by the tick, and its live collector."""

    def __init__(self, service: ServiceView) -> None:
        # A ``_created`` series beside every counter and histogram only clutters: compd's
        # start time is its own gauge. The switch is process-wide, as compd is the process.
        disable_created_metrics()  # type: ignore[no-untyped-call]  # prometheus_client leaves it untyped
        self.registry = CollectorRegistry(auto_describe=True)
        ProcessCollector(registry=self.registry)
        self.lateness = Histogram(
            "compd_tick_lateness_seconds",
            "How long after its deadline each tick started (s of the service's clock).",
            buckets=TICK_BUCKETS_S,
            registry=self.registry,
        )
        self.cpu = Histogram(
            "compd_tick_cpu_seconds",
            "CPU time of each tick's loop core on its thread: read, check, model, safety, write, read back.",
            buckets=TICK_BUCKETS_S,
            registry=self.registry,
        )
        self.io = Histogram(
            "compd_driver_io_seconds",
            "Time of one batched read or write of a driver, timed-out attempts included.",
            ["driver", "operation"],
            buckets=IO_BUCKETS_S,
            registry=self.registry,
        )
        self.registry.register(LiveCollector(service))

    def observe_tick(self, lateness_s: float, cpu_s: float) -> None:
        """One tick's wake-up lateness and CPU time (s)."""
        self.lateness.observe(max(0.0, lateness_s))
        self.cpu.observe(cpu_s)

    def io_observer(self, driver: str) -> Callable[[str, float], None]:
        """What a driver's link calls with ``(operation, seconds)`` after each read or write."""
        children = {op: self.io.labels(driver, op) for op in ("read", "write")}

        def observe(operation: str, seconds: float) -> None:
            children[operation].observe(seconds)

        return observe

    def render(self, accept: str = "") -> tuple[bytes, str]:
        """The metrics and their content type, in the format ``accept`` asks for (Prometheus text by default)."""
        encoder, content_type = choose_encoder(accept)
        return encoder(self.registry), content_type


class LiveCollector(Collector):
    """The service's counters (the last snapshot's) and state, read at each scrape."""

    def __init__(self, service: ServiceView) -> None:
        self.service = service
        self._unverifiable = UnverifiableCache()

    def collect(self) -> Iterator[Metric]:
        service = self.service
        comp = service.compensator
        # The last tick's snapshot: the counters compd status and telemetry give, and its record.
        snapshot = service.last
        counters = _counters(service)
        links = service.links
        doc = service.config.doc
        last = None if snapshot is None else snapshot.record

        yield _counter("compd_ticks", "Ticks run since start.", counters["ticks"])
        yield _counter(
            "compd_overruns", "Deadlines missed because a tick overran.", counters["overruns"]
        )
        faults = CounterMetricFamily(
            "compd_faults",
            "Fault episodes by kind: signal (an input faulted), signal_estimated (an input replaced "
            "by its prediction from the other sensors), driver (a link failed), "
            "write (a tick's writes failed), model (a model failed and was unloaded), "
            "readback_mismatch (an offset read back was not what compd wrote), "
            "offset_out_of_clamp (an offset read back outside its clamp or not finite), "
            "envelope (an axis's target at the clamp or beyond its calibration for envelope_after_s), "
            "redundant_pair (a model input and its second sensor disagreed, or one failed).",
            labels=["kind"],
        )
        faults.add_metric(["signal"], counters["signal_faults"])
        faults.add_metric(["signal_estimated"], counters["signal_estimates"])
        faults.add_metric(["driver"], sum(link.faults for link in links.values()))
        faults.add_metric(["write"], counters["write_failures"])
        faults.add_metric(["model"], counters["model_failures"])
        faults.add_metric(["readback_mismatch"], counters["offset_mismatches"])
        faults.add_metric(["offset_out_of_clamp"], counters["offsets_out_of_clamp"])
        faults.add_metric(["envelope"], counters["envelope_faults"])
        faults.add_metric(["redundant_pair"], counters["redundancy_faults"])
        yield faults

        driver_faults = CounterMetricFamily(
            "compd_driver_faults", "Fault episodes of each driver's link.", labels=["driver"]
        )
        reconnects = CounterMetricFamily(
            "compd_driver_reconnects",
            "Reconnections of each driver after a failure.",
            labels=["driver"],
        )
        up = GaugeMetricFamily(
            "compd_driver_up", "1 while the driver's link is up.", labels=["driver"]
        )
        refusing = GaugeMetricFamily(
            "compd_driver_writes_refused",
            "1 while the driver's device answers writes with a refusal (no write accepted since).",
            labels=["driver"],
        )
        for name, link in links.items():
            driver_faults.add_metric([name], link.faults)
            reconnects.add_metric([name], link.reconnects)
            up.add_metric([name], float(link.up))
            refusing.add_metric([name], float(link.refusing_writes))
        yield from (driver_faults, reconnects, up, refusing)

        offsets = GaugeMetricFamily(
            "compd_offset_meters",
            "The offset the safety stage gives each axis (m).",
            labels=["axis"],
        )
        held = GaugeMetricFamily(
            "compd_offset_held_meters",
            "The offset each axis's controller holds as far as compd knows: read back, else acknowledged (m).",
            labels=["axis"],
        )
        targets = GaugeMetricFamily(
            "compd_offset_target_meters",
            "The model's target offset per axis before clamp and slew (m).",
            labels=["axis"],
        )
        outside = GaugeMetricFamily(
            "compd_offset_outside_envelope_seconds",
            "How long each axis's target has been at the clamp or beyond its model's calibration "
            "(s; 0 inside); a fault from safety.envelope_after_s.",
            labels=["axis"],
        )
        envelope_fault = GaugeMetricFamily(
            "compd_offset_envelope_fault",
            "1 while an axis is in an envelope fault: its target at the clamp or beyond its "
            "model's calibration for safety.envelope_after_s.",
            labels=["axis"],
        )
        known = comp.held.known_um()
        for axis, stage in comp.safety.items():
            outside.add_metric([axis], stage.watch.outside_s)
            envelope_fault.add_metric([axis], float(stage.watch.faulted))
            offsets.add_metric([axis], stage.offset_um * M_PER_UM)
            if axis in known:
                held.add_metric([axis], known[axis] * M_PER_UM)
            if last is not None and axis in last.targets_um:
                targets.add_metric([axis], last.targets_um[axis] * M_PER_UM)
        yield from (offsets, held, targets, outside, envelope_fault)

        # One metric per physical quantity, in its base unit: a query never adds degC to kW.
        values: dict[str, GaugeMetricFamily] = {}
        health = GaugeMetricFamily(
            "compd_signal_health",
            "Each input's health: 0 ok, 1 held, 2 faulted, 3 estimated from the other sensors.",
            labels=["signal"],
        )
        for name, monitor in comp.monitors.items():
            reading = monitor.reading
            unit = doc.signals[name].unit
            suffix, factor = prometheus_unit(unit)
            if suffix not in values:
                values[suffix] = GaugeMetricFamily(
                    f"compd_signal_{suffix}",
                    f"Each input's checked value, in {suffix.replace('_', ' ')} "
                    "(converted from the config's unit).",
                    labels=["signal"],
                )
            if math.isfinite(reading.value):
                values[suffix].add_metric([name], reading.value * factor)
            health.add_metric([name], int(reading.health))
        yield from (*values.values(), health)

        if last is not None:
            yield _gauge(
                "compd_status_word", "The status word last written to the PLC.", last.status
            )
            yield _gauge(
                "compd_status_level",
                "The status level: 0 ok, 1 degraded, 2 faulted.",
                last.status & 0b11,
            )
            flags = GaugeMetricFamily(
                "compd_status_flag",
                "Each flag of the status word last written: 1 set, 0 clear.",
                labels=["flag"],
            )
            for flag in Flag:
                flags.add_metric([flag.name.lower()], float(bool(last.status & flag)))
            yield flags
            yield _gauge(
                "compd_last_tick_timestamp_seconds",
                "When the last tick was due (UTC epoch s).",
                last.wall_unix_s,
            )
        yield _gauge("compd_heartbeat", "The heartbeat counter last written.", comp.heartbeat)
        yield _gauge(
            "compd_start_time_seconds",
            "When the service started (UTC epoch s).",
            service.started_unix_s,
        )
        info = GaugeMetricFamily(
            "compd_info",
            "This compd (value 1): its version and the config's machine_id ('' when it names none).",
            labels=["version", "machine_id"],
        )
        info.add_metric([__version__, doc.machine_id or ""], 1.0)
        yield info
        yield from _model_metrics(service)
        yield from self._unverifiable_metrics()
        yield from _link_metrics(service)
        yield from _probe_metrics(service)

    def _unverifiable_metrics(self) -> Iterator[Metric]:
        """What the sensors cannot verify of the running model (:mod:`compd.service.config.verifiable`)."""
        service = self.service
        slot = service.compensator.running
        if slot is None:
            return
        rows = self._unverifiable.rows(service.config.doc, slot.model_file, slot.compiled)
        yield _unverifiable_gauge(rows)


def _counters(service: ServiceView) -> Mapping[str, int]:
    """The last snapshot's counters (zeros before the first tick, as the compensator's are)."""
    snapshot = service.last
    if snapshot is not None:
        return snapshot.counters
    return vars(service.compensator.counters) | {"overruns": service.timing.overruns}


def _model_metrics(service: ServiceView) -> Iterator[Metric]:
    """The model running, its fit % as its provenance records it, loads and failures."""
    comp = service.compensator
    slot = comp.running
    if slot is None:  # a data logger runs no model
        return
    name, sha = slot.compiled.name, slot.sha256
    info = GaugeMetricFamily(
        "compd_model_info",
        "The model the axes follow (value 1), by name, sha256 and file.",
        labels=["model", "sha256", "path"],
    )
    info.add_metric([name, sha, str(slot.model_file.path)], 1.0)
    yield info
    fit = GaugeMetricFamily(
        "compd_model_fit_ratio",
        "The running model's fit per output (1 = perfect; fit % / 100), as its provenance "
        "records it (compd fit's calibration).",
        labels=["model", "sha256", "output"],
    )
    for output, percent in slot.model_file.doc.provenance.fit_percent.items():
        fit.add_metric([name, sha, output], percent / 100.0)
    yield fit
    yield _counter(
        "compd_model_loads",
        "Models switched in while running (compd model load).",
        _counters(service)["model_loads"],
    )
    yield _gauge(
        "compd_model_fault",
        "1 while the model is faulted (its outputs not finite).",
        float(comp.model_fault is not None),
    )
    yield _gauge(
        "compd_model_blending",
        "1 while a newly loaded model is blended in.",
        float(comp.previous is not None),
    )


def _unverifiable_gauge(rows: list[Unverifiable]) -> Metric:
    gauge = GaugeMetricFamily(
        "compd_unverifiable_error_meters",
        "Per model input and axis, the offset error a wrong reading of the input can cause "
        "before any check sees it (threshold x the model's static sensitivity; +Inf: nothing "
        "checks the input). compd check-config prints it with the axis's tolerance.",
        labels=["input", "axis"],
    )
    for row in rows:
        gauge.add_metric([row.input, row.axis], row.undetectable_um * M_PER_UM)
    return gauge


def _probe_metrics(service: ServiceView) -> Iterator[Metric]:
    """Probes (config ``probes``): how well compensation holds on the parts, the shop's evidence."""
    probing = service.probing
    if probing is None:
        return
    status = probing.status(service.clock_wall())["axes"]
    residue = GaugeMetricFamily(
        "compd_probe_residue_meters",
        "The last probe's innovation per axis: what it measured minus what the model predicted, "
        "before the update (m).",
        labels=["axis"],
    )
    taken = CounterMetricFamily(
        "compd_probes",
        "Probes per axis and result (accepted, flagged, confirmed, rejected, refused; "
        "duplicate and too_soon: answered, not given to the update).",
        labels=["axis", "result"],
    )
    age = GaugeMetricFamily(
        "compd_probe_age_seconds",
        "Time since the last probe the update took, per axis (s; absent before the first).",
        labels=["axis"],
    )
    due = GaugeMetricFamily(
        "compd_probe_due", "1 while a probe is due on the axis.", labels=["axis"]
    )
    disagrees = GaugeMetricFamily(
        "compd_probe_disagrees",
        "1 after two probes in a row the update would not take: the model no longer "
        "describes the machine.",
        labels=["axis"],
    )
    shift = GaugeMetricFamily(
        "compd_probe_shift_rms_meters",
        "The RMS of the axis's probe residues over the last 8 h, a shift (m; absent without "
        "a probe in it): how well compensation held on the parts.",
        labels=["axis"],
    )
    adjustment = GaugeMetricFamily(
        "compd_probe_adjustment_meters",
        "What the probes taught, added to the model's output per axis (m).",
        labels=["axis"],
    )
    for axis, s in status.items():
        last = s["last"]
        if last is not None and last["innovation_um"] is not None:
            residue.add_metric([axis], last["innovation_um"] * M_PER_UM)
        for result, count in s["results"].items():
            taken.add_metric([axis, result], count)
        if s["last_taken_age_s"] is not None:
            age.add_metric([axis], s["last_taken_age_s"])
        due.add_metric([axis], float(s["due"]))
        disagrees.add_metric([axis], float(s["disagrees"]))
        adjustment.add_metric([axis], s["adjustment_um"] * M_PER_UM)
        if s["shift_rms_um"] is not None:
            shift.add_metric([axis], s["shift_rms_um"] * M_PER_UM)
    yield from (residue, taken, age, due, disagrees, shift, adjustment)
    yield _gauge(
        "compd_probe_learning_fault",
        "1 while the probe learning fails or is off (/healthz names why): nothing it taught "
        "is applied where it fails.",
        float(probing.problem() is not None),
    )


def _link_metrics(service: ServiceView) -> Iterator[Metric]:
    """The MQTT link (where telemetry is on) and the recorder (where it records)."""
    if service.telemetry is not None:
        mqtt = service.telemetry.counters
        yield _gauge("compd_mqtt_connected", "1 while connected to the broker.", mqtt.connected)
        yield _counter(
            "compd_mqtt_connections", "Connections made to the broker.", mqtt.connections
        )
        yield _gauge(
            "compd_mqtt_standing_by",
            "1 while another live daemon publishes as this machine_id and this one stands by.",
            service.telemetry.rival is not None,
        )
        yield _counter(
            "compd_mqtt_published", "Messages handed to the MQTT client to send.", mqtt.published
        )
        yield _counter(
            "compd_mqtt_acknowledged",
            "Messages the broker acknowledged (QoS 1).",
            mqtt.acknowledged,
        )
        yield _counter(
            "compd_mqtt_dropped",
            "Snapshots and events dropped: the oldest of a full queue, or refused by the client.",
            mqtt.dropped,
        )
    if (saver := service.saver) is not None:
        yield _gauge(
            "compd_state_saved",
            "1 while the state saves; 0 while saves fail (a restart resumes from an older state).",
            saver.problem() is None,
        )
        yield _counter(
            "compd_state_save_faults",
            "Episodes in which the state could not be saved.",
            saver.fault.episodes,
        )
    fault = service.recorder_fault
    if fault is not None:
        yield _gauge(
            "compd_recorder_up", "1 while the recorder writes; 0 while it fails.", not fault.active
        )
        yield _counter(
            "compd_recorder_faults",
            "Episodes in which the recorder could not write.",
            fault.episodes,
        )


def _counter(name: str, documentation: str, value: float) -> CounterMetricFamily:
    return CounterMetricFamily(name, documentation, value=value)


def _gauge(name: str, documentation: str, value: float) -> GaugeMetricFamily:
    return GaugeMetricFamily(name, documentation, value=value)
