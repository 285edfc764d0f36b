"""The config file's schema: one frozen pydantic document per section, each building its runtime object.

After Klipper, a config section maps to the object it configures: a signal
section builds the point it is read at and the monitor that checks it
(:meth:`SignalDoc.point`, :meth:`SignalDoc.monitor`), an output section the
axis's write point and its safety stage (:meth:`OutputDoc.point`,
:meth:`OutputDoc.stage`), a driver section its driver and the link that
supervises it (:meth:`DriverDoc.driver`, :meth:`DriverDoc.link`), and so on;
the service (:mod:`compd.service.daemon`) only assembles them. Validation
across sections (references, addresses, written points) is
:mod:`compd.service.config.loading`'s.
"""

from __future__ import annotations

import importlib.util
import os
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, Field, StrictInt, model_validator

from compd.drivers.base import Driver
from compd.drivers.registry import load_driver_type
from compd.schemas import CONFIG_SCHEMA
from compd.service.config.admission import Access
from compd.service.config.docbase import FiniteFloat, Positive, Strict
from compd.service.config.fleetdoc import HttpDoc, TelemetryDoc
from compd.service.config.simdoc import SimulationDoc
from compd.service.loop.clock import Clock
from compd.service.loop.envelope import EnvelopeSettings
from compd.service.loop.links import DriverLink
from compd.service.loop.offsets import AxisPoint
from compd.service.loop.plausibility import PlausibilitySettings
from compd.service.loop.points import SignalPoint, StatusPoint
from compd.service.loop.redundancy import Pair
from compd.service.loop.safety import AxisLimits, AxisSafety, FaultMode, OutOfClamp
from compd.service.loop.schedule import GainRow, GainScheduler, GainTable
from compd.service.loop.signals import Checks, SignalMonitor

SCHEMA = CONFIG_SCHEMA
#: Signals beyond this many cannot each have a bit in the 32-bit status word (bits 8..31); the
#: readback-mismatch and model-fault bits follow them where bits are left (:mod:`compd.service.loop.safety`).
MAX_SIGNALS = 24


#: Units of a temperature: stuck detection is on by default for them (a live sensor read at
#: its resolution always shows noise; where one does not, the config says ``stuck_s: null``).
TEMPERATURE_UNITS = frozenset({"degC", "K", "degF"})
#: How long a temperature may read exactly the same value before it is judged stuck (s).
DEFAULT_STUCK_S = 60.0


class ChecksDoc(Strict):
    """Per-signal plausibility checks (see :mod:`compd.service.loop.signals`), in the signal's unit.

    ``stuck_s`` left out: :data:`DEFAULT_STUCK_S` for a temperature, off for
    other units; ``null`` switches it off. ``max_jump`` left out: the model's
    calibration sets it where the model file has a consistency model.
    """

    min: FiniteFloat | None = None
    max: FiniteFloat | None = None
    stale_s: Positive = 10.0
    stuck_s: Positive | None = None
    stuck_tolerance: Annotated[float, Field(ge=0, allow_inf_nan=False)] = 0.0
    max_jump: Positive | None = None
    hold_s: Annotated[float, Field(ge=0, allow_inf_nan=False)] = 30.0

    @model_validator(mode="after")
    def _ordered(self) -> ChecksDoc:
        if self.min is not None and self.max is not None and self.min >= self.max:
            raise ValueError(f"'min' ({self.min}) must be below 'max' ({self.max})")
        return self

    def checks(self, unit: str = "") -> Checks:
        values = self.model_dump()
        if "stuck_s" not in self.model_fields_set and unit in TEMPERATURE_UNITS:
            values["stuck_s"] = DEFAULT_STUCK_S
        return Checks(**values)

    def stuck_off(self, unit: str) -> bool:
        """Whether stuck detection is off for a signal in ``unit`` (check-config lists those)."""
        return self.checks(unit).stuck_s is None


class SignalDoc(Strict):
    """``value = raw * scale + offset`` in ``unit``."""

    driver: str
    address: str = Field(min_length=1)
    type: Literal["float", "int", "bool"] = "float"
    scale: FiniteFloat = 1.0
    offset: FiniteFloat = 0.0
    unit: str
    description: str = ""
    checks: ChecksDoc = ChecksDoc()
    #: A second reading of the same point (another signal's name, e.g. a second Pt100 beside
    #: this one): the pair's disagreement is a fault, and the reading the other sensors
    #: support is used (:mod:`compd.service.loop.redundancy`).
    redundant: str | None = Field(default=None, min_length=1)
    #: How far the pair may disagree beyond their usual offset, in the signal's unit; default
    #: for a temperature :data:`DEFAULT_REDUNDANT_TOLERANCE` (converted to the unit).
    redundant_tolerance: Positive | None = None

    def point(self, name: str) -> SignalPoint:
        """Where the signal ``name`` is read, and how its raw value is scaled."""
        return SignalPoint(name, self.driver, self.address, self.scale, self.offset, self.type)

    def monitor(self, name: str) -> SignalMonitor:
        """The plausibility checks of the signal ``name``, with no reading yet."""
        return SignalMonitor(name, self.checks.checks(self.unit))

    def pair(self, name: str) -> Pair | None:
        """The redundant pair this signal heads (None: it names no partner); needs a tolerance."""
        if self.redundant is None:
            return None
        tolerance = self.redundant_tolerance
        if tolerance is None:
            tolerance = default_redundant_tolerance(self.unit)
        assert tolerance is not None, "checked by the config's cross-checks"
        return Pair(name, self.redundant, tolerance, self.unit)


#: Two class-A Pt100s at one point differ by up to about 0.3 degC (their offsets, IEC 60751),
#: which the pair's learned offset takes off; what is left is noise and the difference of
#: their lags in a transient (up to 0.12 degC on the simulated machine's spindle over 8 h
#: shifts, ``benchmarks/bench_redundancy.py``). A difference from the usual beyond this (degC)
#: is a fault at once; a smaller one that persists is caught by the pair's drift check.
DEFAULT_REDUNDANT_TOLERANCE = 0.5


def default_redundant_tolerance(unit: str) -> float | None:
    """The pair tolerance a signal in ``unit`` gets when its config names none (None: none known)."""
    per_kelvin = {"degC": 1.0, "K": 1.0, "degF": 1.8}.get(unit)
    return None if per_kelvin is None else DEFAULT_REDUNDANT_TOLERANCE * per_kelvin


class EncodingDoc(Strict):
    """How an offset in um is written: ``round(offset_um * scale)`` for ``int``."""

    type: Literal["float", "int"] = "float"
    scale: Positive = 1.0


class OutputDoc(Strict):
    """One compensated axis: ``offset_um = sign * model_output`` after the safety stage."""

    model_output: str
    driver: str
    address: str = Field(min_length=1)
    encoding: EncodingDoc = EncodingDoc()
    sign: Literal[-1, 1] = -1
    max_offset_um: Positive
    max_rate_um_per_s: Positive
    #: Read the offset back each tick and slew from what the PLC holds; default: where the driver can.
    readback: bool | None = None
    #: The accuracy the compensation promises on this axis (um): an input a wrong reading of
    #: which can move the axis further than this unseen is reported as not verifiable
    #: (``compd check-config``, ``compd status``, ``/metrics``). Default: 3 x the model's
    #: calibration RMS residue of this output, at least 1 um (5 um where the file records none).
    tolerance_um: Annotated[float, Field(gt=0, le=10_000, allow_inf_nan=False)] | None = None

    def point(self, axis: str, *, integer: bool | None = None, readback: bool = False) -> AxisPoint:
        """Where the axis's offset is written; ``integer``: whole counts (default: an int encoding).

        Whether the point holds whole counts and is read back depends on its
        driver: :class:`compd.service.config.loading.Config` knows, and passes them.
        """
        whole = self.encoding.type == "int" if integer is None else integer
        return AxisPoint(
            axis,
            self.model_output,
            self.driver,
            self.address,
            float(self.sign),
            self.encoding.scale,
            whole,
            readback=readback,
        )

    def stage(self, period_s: float, safety: SafetyDoc, *, offset_um: float = 0.0) -> AxisSafety:
        """The axis's safety stage at ``period_s``, seeded with ``offset_um`` (um)."""
        return AxisSafety(
            AxisLimits(self.max_offset_um, self.max_rate_um_per_s),
            period_s,
            on_fault=FaultMode(safety.on_fault),
            fault_ramp_after_s=safety.fault_ramp_after_s,
            offset_um=offset_um,
            on_out_of_clamp=OutOfClamp(safety.on_offset_out_of_clamp),
            envelope=safety.envelope(),
        )


class StatusDoc(Strict):
    """Where the status word and the heartbeat counter go, for the PLC's supervision."""

    driver: str
    status_address: str = Field(min_length=1)
    heartbeat_address: str = Field(min_length=1)

    def point(self, *, mismatch_bit: bool, model_fault_bit: bool) -> StatusPoint:
        """Where the status word goes; which of the optional bits its point holds, the config knows."""
        return StatusPoint(
            self.driver,
            self.status_address,
            self.heartbeat_address,
            mismatch_bit=mismatch_bit,
            model_fault_bit=model_fault_bit,
        )


class DriverDoc(Strict):
    type: str
    settings: dict[str, Any] = Field(default_factory=dict)
    timeout_s: Positive = 0.5
    reconnect_min_s: Positive = 1.0
    reconnect_max_s: Positive = 60.0

    def driver(self, settings: BaseModel, *, now: Callable[[], float], base_dir: Path) -> Driver:
        """The driver, not yet opened; its type's module is imported here, not before."""
        return load_driver_type(self.type)(settings, now=now, base_dir=base_dir)

    def link(self, name: str, driver: Driver, clock: Clock) -> DriverLink:
        """The supervision of ``driver``: its timeout and reconnect backoff."""
        return DriverLink(
            name,
            driver,
            clock,
            timeout_s=self.timeout_s,
            backoff_min_s=self.reconnect_min_s,
            backoff_max_s=self.reconnect_max_s,
        )


class SafetyDoc(Strict):
    """``safety:``: what every axis's stage does on a faulted input and on an offset read back out of clamp."""

    on_fault: Literal["ramp", "freeze"] = "ramp"
    fault_ramp_after_s: Annotated[float, Field(ge=0, allow_inf_nan=False)] = 60.0
    #: An offset read back outside ``±max_offset_um`` or not finite is a fault, never followed;
    #: written instead: ``hold`` the last valid offset (at start the resumed one, else 0),
    #: ``edge`` the nearest clamp edge (then slewing on), ``refuse`` nothing until the PLC
    #: holds a value within the clamp (:class:`compd.service.loop.safety.OutOfClamp`).
    on_offset_out_of_clamp: Literal["hold", "edge", "refuse"] = "hold"
    #: An axis's target at the clamp, or beyond the running model's calibrated output range
    #: by this fraction of the range's span (null: the clamp only), for ``envelope_after_s``
    #: on end is a fault: ``on_fault`` applies, status faulted with the model-fault bit
    #: (:mod:`compd.service.loop.envelope`).
    envelope_margin: Annotated[float, Field(ge=0, le=10, allow_inf_nan=False)] | None = 0.25
    envelope_after_s: Annotated[float, Field(gt=0, le=86_400, allow_inf_nan=False)] = 300.0

    def envelope(self) -> EnvelopeSettings:
        """The envelope's settings for every axis's stage."""
        return EnvelopeSettings(self.envelope_margin, self.envelope_after_s)


class PlausibilityDoc(Strict):
    """``plausibility:``: every model input checked against its prediction from the others.

    Needs a model file with a consistency model (``compd fit`` writes one);
    see :mod:`compd.service.loop.plausibility`. ``enabled: false`` checks each
    input on its own only, as before.
    """

    enabled: bool = True
    #: A reading this many residue sigmas from its prediction is wrong...
    k_sigma: Annotated[float, Field(ge=1, allow_inf_nan=False)] = 8.0
    #: ...and never closer than this, in the signal's unit.
    min_tolerance: Positive = 3.0
    #: Ticks a returning sensor must agree with the others before it is used again.
    confirm_ticks: int = Field(default=30, ge=1, le=86_400)
    #: A slow departure from the hour's level: the CUSUM's allowance (sigmas; drifts faster
    #: than about this many sigmas an hour are caught)...
    drift_k_sigma: Annotated[float, Field(gt=0, le=100, allow_inf_nan=False)] = 3.0
    #: ...and its alarm threshold (sigma-hours; lower catches sooner and errs more often).
    drift_h_sigma_h: Annotated[float, Field(gt=0, le=100, allow_inf_nan=False)] = 0.25
    #: A stand-in ends once the residue is back within this many sigmas of its level before
    #: the episode (grown with the episode's length)...
    release_k_sigma: Annotated[float, Field(gt=0, le=100, allow_inf_nan=False)] = 3.0
    #: ...never closer than this (the signal's unit).
    release_floor: Annotated[float, Field(gt=0, le=1e6, allow_inf_nan=False)] = 0.1

    def settings(self) -> PlausibilitySettings | None:
        if not self.enabled:
            return None
        return PlausibilitySettings(
            self.k_sigma,
            self.min_tolerance,
            self.confirm_ticks,
            drift_k_sigma=self.drift_k_sigma,
            drift_h_sigma_h=self.drift_h_sigma_h,
            release_k_sigma=self.release_k_sigma,
            release_floor=self.release_floor,
        )


class StateDoc(Strict):
    directory: str | None = None
    save_every_ticks: int = Field(default=60, ge=1)
    resume_max_age_s: Annotated[float, Field(ge=0, allow_inf_nan=False)] = 900.0
    #: Without a state to resume: ``thermal_zero`` starts each model at the steady state for
    #: the current inputs from its calibration's thermal zero (drift before the start is
    #: compensated at once); ``now`` takes today's readings as the zero and starts at rest,
    #: offsets from 0 (a shop that touches off the warm machine whenever compd starts, so
    #: that the work offset already holds the drift so far).
    fresh_start: Literal["thermal_zero", "now"] = "thermal_zero"


class RecorderDoc(Strict):
    """``recorder:``: where and how each tick is logged (:mod:`compd.service.recording.recorder`)."""

    enabled: bool = True
    directory: str | None = None
    #: ``csv`` (a row is on disk when written) or ``parquet`` (typed, compressed; a row group
    #: every ``flush_every_rows`` rows, :mod:`compd.service.recording.parquet`).
    format: Literal["csv", "parquet"] = "csv"
    #: Rows gathered per write: default 1 for CSV, 60 for Parquet; a crash loses at most these.
    flush_every_rows: int | None = Field(default=None, ge=1, le=86_400)
    max_file_bytes: int = Field(default=20_000_000, ge=1024)
    max_file_age_s: Positive = 86_400.0
    max_total_bytes: int = Field(default=2_000_000_000, ge=1024)

    @model_validator(mode="after")
    def _parquet_needs_pyarrow(self) -> RecorderDoc:
        # Found, not imported: the daemon loads pyarrow at the first write only.
        if self.format == "parquet" and importlib.util.find_spec("pyarrow") is None:
            raise ValueError(
                "'format: parquet' needs pyarrow, which is not installed: "
                "pip install 'compd[parquet]', or use 'format: csv'"
            )
        return self

    @model_validator(mode="after")
    def _total_holds_a_file(self) -> RecorderDoc:
        if self.max_total_bytes < self.max_file_bytes:
            raise ValueError(
                f"'max_total_bytes' ({self.max_total_bytes}) must be at least 'max_file_bytes' "
                f"({self.max_file_bytes}): the open file alone may reach that size"
            )
        return self


class EffectDoc(Strict):
    """An entry of the effect catalogue: a physical effect and the signals that excite it."""

    description: str = ""
    signals: list[str] = Field(default_factory=list)


class WhenDoc(Strict):
    """A gain-table key: ``when: 2`` (a whole number) or ``when: {min: 0, max: 250}`` (``min <= key < max``)."""

    value: StrictInt | None = None
    min: FiniteFloat | None = None
    max: FiniteFloat | None = None

    @model_validator(mode="before")
    @classmethod
    def _whole_or_range(cls, data: object) -> object:
        if isinstance(data, int) and not isinstance(data, bool):
            return {"value": data}
        if not isinstance(data, dict) or "value" in data:
            raise ValueError(
                "'when' must be a whole number (a head or program number, e.g. 'when: 2') "
                f"or a range (e.g. 'when: {{min: 0, max: 250}}'), got {data!r}"
            )
        return data

    @model_validator(mode="after")
    def _ordered(self) -> WhenDoc:
        if self.value is None and self.min is None and self.max is None:
            raise ValueError("a range needs 'min', 'max' or both")
        if self.min is not None and self.max is not None and self.min >= self.max:
            raise ValueError(f"'min' ({self.min}) must be below 'max' ({self.max})")
        return self


class GainRowDoc(Strict):
    """A row of the gain table: ``gains`` (gain_name -> value) while the key matches ``when``."""

    when: WhenDoc
    gains: dict[str, FiniteFloat] = Field(min_length=1)

    def row(self) -> GainRow:
        when = self.when
        return GainRow(
            dict(self.gains),
            value=when.value,
            low=float("-inf") if when.min is None else when.min,
            high=float("inf") if when.max is None else when.max,
        )


class GainScheduleDoc(Strict):
    """Gains by operating condition (see :mod:`compd.service.loop.schedule`)."""

    signal: str
    table: list[GainRowDoc] = Field(min_length=1)
    default: dict[str, FiniteFloat] | None = None
    ramp_s: Annotated[float, Field(ge=0, allow_inf_nan=False)] = 30.0

    def gain_table(self) -> GainTable:
        default = None if self.default is None else dict(self.default)
        return GainTable(self.signal, tuple(r.row() for r in self.table), default, self.ramp_s)

    def scheduler(self) -> GainScheduler:
        return GainScheduler(self.gain_table())


class LoadAccessDoc(Strict):
    """Who may switch the running model over the control socket (``compd model load``).

    Users and groups by name or number; a client is allowed when its uid is
    listed or its primary gid is (the kernel reports one gid per connection).
    Unset ``users``: the daemon's own user and root. ``compd status`` is open
    to everyone who can open the socket (its group).
    """

    users: list[str | int] | None = None
    groups: list[str | int] = Field(default_factory=list)

    def ids(self) -> tuple[frozenset[int], frozenset[int]]:
        """The uids and gids; raises LookupError naming an unknown user or group."""
        import grp
        import pwd

        users = [os.getuid(), 0] if self.users is None else self.users
        uids = [u if isinstance(u, int) else pwd.getpwnam(u).pw_uid for u in users]
        gids = [g if isinstance(g, int) else grp.getgrnam(g).gr_gid for g in self.groups]
        return frozenset(uids), frozenset(gids)

    def access(self) -> Access:
        """Who may load a model, as the control socket checks it."""
        return Access(*self.ids())


class ProbeAxisDoc(Strict):
    """One axis's probe interface on the PLC: what its probe cycle writes, what compd answers.

    The PLC's probe cycle writes the measured value (``value_address``, um as
    ``raw * value_scale``), then increments ``counter_address``; compd takes
    each new count once, and writes the last count it took to ``echo_address``
    (a value is never used twice or missed, across restarts too). Where the
    PLC stamps the touch (``touched_at_address``, unix s), the value refers
    to that instant; without, to the tick that saw the count change.
    ``status_address`` (optional) gets bit 0 "probe due", bit 1 "the model
    no longer describes the machine" (two probes in a row rejected).
    """

    driver: str
    value_address: str = Field(min_length=1)
    value_scale: FiniteFloat = 1.0
    counter_address: str = Field(min_length=1)
    echo_address: str = Field(min_length=1)
    touched_at_address: str | None = Field(default=None, min_length=1)
    status_address: str | None = Field(default=None, min_length=1)


class ProbesDoc(Strict):
    """``probes:``: probe measurements update the running model in service (:mod:`compd.service.loop.probing`).

    ``measures``: with compensation active a probe sees the residue (what is
    left after the offset in force when it touched); ``thermal_error`` for a
    probe that reports the uncompensated drift. The update's settings default
    to the model file's ``probe_prior`` (or a documented conservative default):
    ``probe_noise_um`` 0.5 um; ``drift_um_per_sqrt_h`` 0.3 calibration sigma per
    sqrt(hour); ``reject_sigma`` 4 (a probe further than that from the
    prediction is flagged, taken only when the next confirms it).
    ``min_gap_s``: one probe per axis is given to the update per this much
    touch time (a resend is answered as it was taken; a confirmation is a
    separate touch); ``max_shift_um``: the largest learned shift (the bias,
    what no gain scales) the probes reach without a person (default
    twice ``max_departure_um``: the model's largest output; ``compd model
    probe --accept-shift`` takes more).
    """

    enabled: bool = True
    measures: Literal["residue", "thermal_error"] = "residue"
    #: A probe is due this long after the last one taken (h): the PLC probes at its next tool change.
    every_h: Annotated[float, Field(gt=0, le=24 * 365, allow_inf_nan=False)] = 2.0
    probe_noise_um: Annotated[float, Field(gt=0, le=1000, allow_inf_nan=False)] | None = None
    drift_um_per_sqrt_h: Annotated[float, Field(ge=0, le=1000, allow_inf_nan=False)] | None = None
    max_departure_um: Annotated[float, Field(gt=0, le=10000, allow_inf_nan=False)] | None = None
    reject_sigma: Annotated[float, Field(gt=0, le=100, allow_inf_nan=False)] | None = None
    #: A probe is flagged only beyond this too (um; default a quarter of the model's largest
    #: output: a model off by its error on a new programme is not a mis-probe).
    reject_floor_um: Annotated[float, Field(ge=0, le=10000, allow_inf_nan=False)] | None = None
    #: One probe per axis per this much touch time (s; the PLC's probe gap, a tool change).
    min_gap_s: Annotated[float, Field(ge=0, le=24 * 3600, allow_inf_nan=False)] = 900.0
    #: The learned shift's bound without a person (um, the bias; default the model's largest output).
    max_shift_um: Annotated[float, Field(gt=0, le=1000, allow_inf_nan=False)] | None = None
    #: Per axis (a name under ``outputs``), where the PLC's probe cycle meets compd; an axis
    #: may also be probed through ``compd model probe`` and MQTT alone (``{}``: no registers).
    axes: dict[str, ProbeAxisDoc | None] = Field(default_factory=dict)

    def overrides(self) -> dict[str, float]:
        """The settings given, as :meth:`compd.model.probesettings.ProbeSettings.defaults` takes them."""
        given = {
            "probe_noise_um": self.probe_noise_um,
            "drift_um_per_sqrt_h": self.drift_um_per_sqrt_h,
            "max_departure_um": self.max_departure_um,
            "reject_sigma": self.reject_sigma,
            "reject_floor_um": self.reject_floor_um,
            "max_shift_um": self.max_shift_um,
        }
        return {k: v for k, v in given.items() if v is not None}


class ConfigDoc(Strict):
    schema_: Literal["compd.config/1"] = Field(alias="schema")
    #: This machine's name across a fleet: in every recording's metadata (and telemetry's topics).
    machine_id: (
        Annotated[str, Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9._-]+\Z")] | None
    ) = None
    #: The model file; a config without ``outputs`` (a data logger, ``compd record``) needs none.
    model: str | None = None
    period_s: Positive = 1.0
    blend_s: Annotated[float, Field(ge=0, allow_inf_nan=False)] = 60.0
    live_every_ticks: int = Field(default=60, ge=1)
    control_socket: str | None = None
    load_access: LoadAccessDoc = LoadAccessDoc()
    drivers: dict[str, DriverDoc] = Field(min_length=1)
    signals: dict[str, SignalDoc] = Field(min_length=1, max_length=MAX_SIGNALS)
    #: Empty: a data logger, reading, checking and recording the signals, writing nothing.
    outputs: dict[str, OutputDoc] = Field(default_factory=dict)
    status: StatusDoc | None = None
    safety: SafetyDoc = SafetyDoc()
    plausibility: PlausibilityDoc = PlausibilityDoc()
    state: StateDoc = StateDoc()
    recorder: RecorderDoc = RecorderDoc()
    effects: dict[str, EffectDoc] = Field(default_factory=dict)
    gain_schedule: GainScheduleDoc | None = None
    #: MQTT telemetry to a fleet's broker (:mod:`compd.service.fleet.telemetry`); none without.
    telemetry: TelemetryDoc | None = None
    #: Prometheus metrics and the read-only status page (:mod:`compd.service.http.server`).
    http: HttpDoc | None = None
    #: Probe measurements that update the model in service; none without.
    probes: ProbesDoc | None = None
    #: The simulated machine this config runs against (:mod:`compd.service.config.simdoc`).
    simulation: SimulationDoc | None = None

    def pairs(self) -> list[Pair]:
        """The redundant pairs: each signal naming a partner (``redundant:``), in config order."""
        return [p for name, s in self.signals.items() if (p := s.pair(name)) is not None]

    @model_validator(mode="before")
    @classmethod
    def _one_machine_id(cls, data: Any) -> Any:
        """Telemetry's topics name the machine as its recordings do: ``telemetry.machine_id``
        defaults to the top-level ``machine_id``, and the two may not differ."""
        if not isinstance(data, dict) or not isinstance(data.get("telemetry"), dict):
            return data
        top, own = data.get("machine_id"), data["telemetry"].get("machine_id")
        if own is None and top is not None:
            return data | {"telemetry": data["telemetry"] | {"machine_id": top}}
        if own is not None and top is not None and own != top:
            raise ValueError(
                f"telemetry.machine_id {own!r} differs from machine_id {top!r}: name the "
                "machine once, at the top"
            )
        return data
