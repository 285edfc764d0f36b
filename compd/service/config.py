"""The daemon's configuration file: parsed and validated once, into frozen objects, before any I/O.

One YAML file (``schema: compd.config/1``) wires the machine to the model:
drivers (bus connections), signals (name -> driver address, scaling, checks),
outputs (axis -> model output, driver address, encoding, limits), the status
word and heartbeat, the model path, the period, directories and safety
options. Unknown keys, wrong types and dangling references (a signal naming
an undefined driver, a model input without a signal) are errors reading
``FILE: line N (signals.T_spindle.driver): what is wrong. fix``; any of them
stops ``compd run`` before the first write to a machine, and
``compd check-config`` runs exactly the same validation.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

import yaml
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    StrictInt,
    ValidationError,
    model_validator,
)

from compd.drivers.base import DriverType, address_syntax, check_address
from compd.drivers.registry import (
    DriverImportError,
    UnknownDriverError,
    driver_names,
    load_driver_type,
)
from compd.errors import ConfigFileError
from compd.files.modelfile import ModelFile
from compd.files.yamlplace import (
    FIXES,
    describe,
    parse_yaml,
    read_limited,
    resolve_path,
    shorten,
    where,
)
from compd.model.compiled import CompiledModel
from compd.service.paths import control_socket_of, state_dir_of
from compd.service.schedule import GainRow, GainTable, first_overlap, model_gains
from compd.service.writepoints import (
    check_written,
    output_readback,
    status_mismatch_bit,
    status_model_fault_bit,
    whole_counts,
    written_points,
)

SCHEMA = "compd.config/1"
#: Signals beyond this many cannot each have a bit in the 32-bit status word (bits 8..31); the
#: readback-mismatch and model-fault bits follow them where bits are left (:mod:`compd.service.safety`).
MAX_SIGNALS = 24

FiniteFloat = Annotated[float, Field(allow_inf_nan=False)]
Positive = Annotated[float, Field(gt=0, allow_inf_nan=False)]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class ChecksDoc(_Strict):
    """Per-signal plausibility checks (see :mod:`compd.service.signals`), in the signal's unit."""

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


class SignalDoc(_Strict):
    """``value = raw * scale + offset`` in ``unit``."""

    driver: str
    address: str = Field(min_length=1)
    type: Literal["float", "int", "bool"] = "float"
    scale: FiniteFloat = 1.0
    offset: FiniteFloat = 0.0
    unit: str
    description: str = ""
    checks: ChecksDoc = ChecksDoc()


class EncodingDoc(_Strict):
    """How an offset in um is written: ``round(offset_um * scale)`` for ``int``."""

    type: Literal["float", "int"] = "float"
    scale: Positive = 1.0


class OutputDoc(_Strict):
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


class StatusDoc(_Strict):
    """Where the status word and the heartbeat counter go, for the PLC's supervision."""

    driver: str
    status_address: str = Field(min_length=1)
    heartbeat_address: str = Field(min_length=1)


class DriverDoc(_Strict):
    type: str
    settings: dict[str, Any] = Field(default_factory=dict)
    timeout_s: Positive = 0.5
    reconnect_min_s: Positive = 1.0
    reconnect_max_s: Positive = 60.0


class SafetyDoc(_Strict):
    on_fault: Literal["ramp", "freeze"] = "ramp"
    fault_ramp_after_s: Annotated[float, Field(ge=0, allow_inf_nan=False)] = 60.0


class StateDoc(_Strict):
    directory: str | None = None
    save_every_ticks: int = Field(default=60, ge=1)
    resume_max_age_s: Annotated[float, Field(ge=0, allow_inf_nan=False)] = 900.0


class RecorderDoc(_Strict):
    enabled: bool = True
    directory: str | None = None
    max_file_bytes: int = Field(default=20_000_000, ge=1024)
    max_file_age_s: Positive = 86_400.0
    max_total_bytes: int = Field(default=2_000_000_000, ge=1024)

    @model_validator(mode="after")
    def _total_holds_a_file(self) -> RecorderDoc:
        if self.max_total_bytes < self.max_file_bytes:
            raise ValueError(
                f"'max_total_bytes' ({self.max_total_bytes}) must be at least 'max_file_bytes' "
                f"({self.max_file_bytes}): the open file alone may reach that size"
            )
        return self


class EffectDoc(_Strict):
    """An entry of the effect catalogue: a physical effect and the signals that excite it."""

    description: str = ""
    signals: list[str] = Field(default_factory=list)


class WhenDoc(_Strict):
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


class GainRowDoc(_Strict):
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


class GainScheduleDoc(_Strict):
    """Gains by operating condition (see :mod:`compd.service.schedule`)."""

    signal: str
    table: list[GainRowDoc] = Field(min_length=1)
    default: dict[str, FiniteFloat] | None = None
    ramp_s: Annotated[float, Field(ge=0, allow_inf_nan=False)] = 30.0

    def gain_table(self) -> GainTable:
        default = None if self.default is None else dict(self.default)
        return GainTable(self.signal, tuple(r.row() for r in self.table), default, self.ramp_s)


class LoadAccessDoc(_Strict):
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


class ConfigDoc(_Strict):
    schema_: Literal["compd.config/1"] = Field(alias="schema")
    model: str
    period_s: Positive = 1.0
    blend_s: Annotated[float, Field(ge=0, allow_inf_nan=False)] = 60.0
    live_every_ticks: int = Field(default=60, ge=1)
    control_socket: str | None = None
    load_access: LoadAccessDoc = LoadAccessDoc()
    drivers: dict[str, DriverDoc] = Field(min_length=1)
    signals: dict[str, SignalDoc] = Field(min_length=1, max_length=MAX_SIGNALS)
    outputs: dict[str, OutputDoc] = Field(min_length=1)
    status: StatusDoc | None = None
    safety: SafetyDoc = SafetyDoc()
    state: StateDoc = StateDoc()
    recorder: RecorderDoc = RecorderDoc()
    effects: dict[str, EffectDoc] = Field(default_factory=dict)
    gain_schedule: GainScheduleDoc | None = None
    #: The simulated machine this config runs against (:mod:`compd.sim.plc.settings`).
    simulation: dict[str, Any] | None = None


@dataclass(frozen=True)
class Config:
    """A validated configuration with every path resolved and every driver's settings parsed."""

    path: Path
    doc: ConfigDoc
    model_path: Path
    state_dir: Path
    recorder_dir: Path | None
    control_socket: Path
    driver_settings: dict[str, BaseModel]
    #: The ``simulation:`` section as written: the service never reads it; the
    #: command line and :mod:`compd.sim.plc.settings` validate it and start the twin.
    simulation: Mapping[str, Any] | None = None
    #: Per axis: the offset is read back each tick (:mod:`compd.service.writepoints`).
    readback: dict[str, bool] = field(default_factory=dict)
    #: Per axis: its point holds whole counts (an int encoding, or an integer register).
    whole_counts: dict[str, bool] = field(default_factory=dict)
    #: The status word's readback-mismatch bit, if the status point holds it.
    mismatch_bit: int | None = None
    #: The status word's model-fault bit, where its point holds it (None: logged and counted only).
    model_fault_bit: int | None = None
    #: The YAML node tree, for the line numbers of errors found later (:func:`check_model`).
    root: yaml.Node | None = field(default=None, repr=False, compare=False)

    @property
    def base_dir(self) -> Path:
        return self.path.parent

    @property
    def signal_names(self) -> tuple[str, ...]:
        return tuple(self.doc.signals)


def load_config(path: str | Path) -> Config:
    """Read and validate a config file (schema and references; see :func:`check_model`)."""
    path = Path(path)
    text = read_limited(path, ConfigFileError).decode("utf-8", errors="replace")
    return parse_config(text, path)


def parse_config(text: str, path: Path) -> Config:
    data, root = parse_yaml(text, path, ConfigFileError)
    if not isinstance(data, dict) or data.get("schema") != SCHEMA:
        shown = data.get("schema") if isinstance(data, dict) else None
        raise ConfigFileError(
            path,
            f"unsupported or missing schema {shorten(shown)}",
            where="schema",
            fix=f"Start the file with 'schema: {SCHEMA}' (see config/compd.example.yaml)",
        )
    try:
        doc = ConfigDoc.model_validate(data)
    except ValidationError as exc:
        raise validation_error(exc, path, root, ()) from exc

    def error(location: tuple[str | int, ...], message: str, fix: str) -> ConfigFileError:
        return ConfigFileError(path, message, where=where(root, location), fix=fix)

    types: dict[str, DriverType] = {}
    settings: dict[str, BaseModel] = {}
    for name, driver in doc.drivers.items():
        try:
            types[driver.type] = load_driver_type(driver.type)
        except UnknownDriverError:
            raise error(
                ("drivers", name, "type"),
                f"unknown driver type {driver.type!r}",
                f"Use one of {driver_names()}",
            ) from None
        except DriverImportError as exc:
            raise error(
                ("drivers", name, "type"),
                str(exc),
                "Install the library it names (pip install compd reinstalls compd's own)",
            ) from exc
        try:
            settings[name] = types[driver.type].settings_model.model_validate(driver.settings)
        except ValidationError as exc:
            raise validation_error(exc, path, root, ("drivers", name, "settings")) from exc
    drivers = sorted(doc.drivers)
    references: list[tuple[tuple[str | int, ...], str]] = [
        (("signals", n, "driver"), s.driver) for n, s in doc.signals.items()
    ]
    references += [(("outputs", n, "driver"), o.driver) for n, o in doc.outputs.items()]
    if doc.status is not None:
        references.append((("status", "driver"), doc.status.driver))
    for location, driver_name in references:
        if driver_name not in doc.drivers:
            raise error(
                location,
                f"driver {driver_name!r} is not defined under 'drivers'",
                f"Define it or use one of {drivers}",
            )
    for name, effect in doc.effects.items():
        for i, signal in enumerate(effect.signals):
            if signal not in doc.signals:
                raise error(
                    ("effects", name, "signals", i),
                    f"signal {signal!r} is not defined under 'signals'",
                    f"Define it or use one of {sorted(doc.signals)}",
                )
    schedule = doc.gain_schedule
    if schedule is not None:
        if schedule.signal not in doc.signals:
            raise error(
                ("gain_schedule", "signal"),
                f"signal {schedule.signal!r} is not defined under 'signals'",
                f"Define it (e.g. the spindle head number, type: int) or use one of "
                f"{sorted(doc.signals)}",
            )
        overlap = first_overlap([r.row() for r in schedule.table])
        if overlap is not None:
            i, j = overlap
            raise error(
                ("gain_schedule", "table", j, "when"),
                f"row {j} overlaps row {i}: some value of {schedule.signal!r} would match both",
                "Make the rows disjoint (ranges are min <= value < max, so [0, 250) and "
                "[250, 500) do not overlap)",
            )
    written = written_points(doc)
    # Each driver type checks its own address grammar (compd.drivers.base.AddressHooks).
    read = [(("signals", n, "address"), s.driver, s.address) for n, s in doc.signals.items()]
    for locations, writable in ((read, False), (written, True)):
        for location, driver_name, address in locations:
            kind = types[doc.drivers[driver_name].type]
            try:
                check_address(kind, address, writable=writable, settings=settings[driver_name])
            except ValueError as exc:
                raise error(
                    location,
                    f"address {address!r} for driver {driver_name!r}: {exc}",
                    f"Write it {address_syntax(kind)}",
                ) from exc
    check_written(doc, types, settings, error)
    readback = output_readback(doc, types, settings, error)

    try:
        doc.load_access.ids()
    except KeyError as exc:
        raise error(
            ("load_access",), f"no such user or group: {exc}", "Give an existing name or a number"
        ) from exc
    state_dir = state_dir_of(doc.state.directory, path.parent)
    recorder_dir = None
    if doc.recorder.enabled:
        recorder_dir = (
            resolve_path(doc.recorder.directory, path.parent)
            if doc.recorder.directory
            else state_dir / "records"
        )
    socket = control_socket_of(doc.control_socket, state_dir, path.parent)
    return Config(
        path=path,
        doc=doc,
        model_path=resolve_path(doc.model, path.parent),
        state_dir=state_dir,
        recorder_dir=recorder_dir,
        control_socket=socket,
        driver_settings=settings,
        simulation=doc.simulation,
        readback=readback,
        whole_counts=whole_counts(doc, types, settings),
        mismatch_bit=status_mismatch_bit(doc, types, settings),
        model_fault_bit=status_model_fault_bit(doc, types, settings),
        root=root,
    )


def check_model(config: Config, model_file: ModelFile, compiled: CompiledModel) -> None:
    """Refuse a model this config cannot run: an input without a signal, an axis without an output."""
    missing = [s for s in compiled.signals if s not in config.doc.signals]
    if missing:
        raise ConfigFileError(
            config.path,
            f"model {model_file.path} reads signal(s) {missing} that are not defined",
            where="signals",
            fix=f"Add them under 'signals' (defined: {sorted(config.doc.signals)})",
        )
    for axis, output in config.doc.outputs.items():
        if output.model_output not in compiled.output_names:
            raise ConfigFileError(
                config.path,
                f"model {model_file.path} has no output {output.model_output!r}",
                where=f"outputs.{axis}.model_output",
                fix=f"Use one of {list(compiled.output_names)}",
            )
    if config.doc.gain_schedule is not None:
        _check_gain_names(config, config.doc.gain_schedule, model_file, compiled)


def _check_gain_names(
    config: Config, schedule: GainScheduleDoc, model_file: ModelFile, compiled: CompiledModel
) -> None:
    """Every gain the schedule sets must be a ``gain_name`` of the model."""
    known = model_gains(compiled)
    places: list[tuple[tuple[str | int, ...], dict[str, float]]] = [
        (("gain_schedule", "table", i, "gains"), row.gains) for i, row in enumerate(schedule.table)
    ]
    if schedule.default is not None:
        places.append((("gain_schedule", "default"), schedule.default))
    for location, gains in places:
        for name in gains:
            if name not in known:
                fix = (
                    f"Use one of {sorted(known)}"
                    if known
                    else "Name the gains in the model file ('gain_name: g1' on the sub-models "
                    "they scale, seed 002 eq. 6), or remove 'gain_schedule'"
                )
                raise ConfigFileError(
                    config.path,
                    f"model {model_file.path} has no gain named {name!r}",
                    where=where(config.root, (*location, name)),
                    fix=fix,
                )


def validation_error(
    exc: ValidationError, path: Path, root: yaml.Node | None, prefix: tuple[str | int, ...]
) -> ConfigFileError:
    """The first of pydantic's complaints about the section at ``prefix``, placed in the file."""
    # A misspelt key shows up as "unknown key" plus "missing key"; the
    # unknown one is the more useful to report.
    errors = sorted(exc.errors(), key=lambda e: e["type"] != "extra_forbidden")
    first = errors[0]
    location = (*prefix, *first["loc"])
    fix = FIXES.get(first["type"], "")
    if first["type"] == "extra_forbidden":
        fix += " (see config/compd.example.yaml for every key)"
    return ConfigFileError(path, describe(first), where=where(root, location), fix=fix)
