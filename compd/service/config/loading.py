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

Each section's schema, and the runtime object it builds, is in
:mod:`compd.service.config.docs`; the checks here span sections (a reference
from one to another, an address a driver type must accept), run in the order
:func:`parse_config` lists them. Where the daemon's files go is
:mod:`compd.service.config.paths`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING

from pydantic import BaseModel, ValidationError

from compd.drivers.base import Driver, DriverType, address_syntax, check_address, check_host
from compd.drivers.registry import (
    DriverImportError,
    UnknownDriverError,
    driver_names,
    load_driver_type,
)
from compd.errors import ConfigFileError
from compd.files.keyhints import unknown_key_hint
from compd.files.yamlplace import (
    FIXES,
    NodeTree,
    describe,
    parse_yaml,
    read_limited,
    resolve_path,
    shorten,
    where,
)
from compd.service.config import paths
from compd.service.config.docs import SCHEMA, ConfigDoc, default_redundant_tolerance
from compd.service.config.overlaps import check_overlaps
from compd.service.config.overrides import apply_overrides
from compd.service.config.simdoc import SimulationDoc
from compd.service.config.writepoints import (
    ErrorAt,
    HookCall,
    check_written,
    output_readback,
    probe_axes,
    read_points,
    status_mismatch_bit,
    status_model_fault_bit,
    whole_counts,
    written_points,
)
from compd.service.loop.offsets import AxisPoint
from compd.service.loop.points import StatusPoint
from compd.service.loop.schedule import first_overlap

if TYPE_CHECKING:  # annotations only: a config is read without loading the model stack
    pass


@dataclass(frozen=True)
class Config:
    """A validated configuration with every path resolved and every driver's settings parsed."""

    path: Path
    doc: ConfigDoc
    #: None for a data logger (no ``outputs``, no ``model``): it records, it compensates nothing.
    model_path: Path | None
    state_dir: Path
    recorder_dir: Path | None
    control_socket: Path
    driver_settings: dict[str, BaseModel]
    #: The ``simulation:`` section (:mod:`compd.service.config.simdoc`): the service never
    #: reads it; the command line starts the twin from it (:mod:`compd.sim.plc.build`).
    simulation: SimulationDoc | None = None
    #: Per axis: the offset is read back each tick (:mod:`compd.service.config.writepoints`).
    readback: dict[str, bool] = field(default_factory=dict)
    #: Per axis: its point holds whole counts (an int encoding, or an integer register).
    whole_counts: dict[str, bool] = field(default_factory=dict)
    #: The status word's readback-mismatch bit, if the status point holds it.
    mismatch_bit: int | None = None
    #: The status word's model-fault bit, where its point holds it (None: logged and counted only).
    model_fault_bit: int | None = None
    #: ``KEY=VALUE`` set on the command line (``--set``); a reload applies them again.
    overrides: tuple[str, ...] = ()
    #: The YAML node tree, for the line numbers of errors found later (:func:`check_model`).
    root: NodeTree | None = field(default=None, repr=False, compare=False)

    @property
    def base_dir(self) -> Path:
        return self.path.parent

    @property
    def signal_names(self) -> tuple[str, ...]:
        return tuple(self.doc.signals)

    @property
    def logger(self) -> bool:
        """A data logger: no outputs and no model; signals read, checked and recorded, nothing written."""
        return self.model_path is None

    def recording(self, directory: Path, *, max_file_bytes: int) -> Config:
        """This config as ``compd record`` runs it: its signals only, recorded into ``directory``.

        Outputs, model and status word are dropped, so nothing is ever written
        to the machine; a recording is never deleted to make room (the
        recorder's ``max_total_bytes`` is lifted), and a file is rotated by
        size only, at ``max_file_bytes``.
        """
        recorder = self.doc.recorder.model_copy(
            update={
                "enabled": True,
                "directory": str(directory),
                "max_file_bytes": max_file_bytes,
                "max_file_age_s": float("inf"),
                "max_total_bytes": 2**62,
            }
        )
        doc = self.doc.model_copy(
            update={"outputs": {}, "model": None, "status": None, "recorder": recorder}
        )
        return replace(
            self,
            doc=doc,
            model_path=None,
            recorder_dir=directory,
            readback={},
            whole_counts={},
            mismatch_bit=None,
            model_fault_bit=None,
        )

    def axis_points(self) -> list[AxisPoint]:
        """Each output's write point, with what its driver says of it (whole counts, readback)."""
        return [
            out.point(
                axis,
                integer=self.whole_counts.get(axis),
                readback=self.readback.get(axis, False),
            )
            for axis, out in self.doc.outputs.items()
        ]

    def status_point(self) -> StatusPoint | None:
        """The status word's point, with the optional bits its register holds; None without one."""
        status = self.doc.status
        if status is None:
            return None
        return status.point(
            mismatch_bit=self.mismatch_bit is not None,
            model_fault_bit=self.model_fault_bit is not None,
        )

    def build_drivers(self, now: Callable[[], float]) -> dict[str, Driver]:
        """One driver per ``drivers`` entry, none opened yet."""
        return {
            name: driver.driver(self.driver_settings[name], now=now, base_dir=self.base_dir)
            for name, driver in self.doc.drivers.items()
        }


def load_config(path: str | Path, overrides: Sequence[str] = ()) -> Config:
    """Read and validate a config file (schema and references; see :func:`check_model`).

    ``overrides``: ``KEY=VALUE`` keys set on the command line (:mod:`compd.service.config.overrides`).
    """
    path = Path(path)
    text = read_limited(path, ConfigFileError).decode("utf-8", errors="replace")
    try:
        return parse_config(text, path, overrides)
    except ConfigFileError as error:
        if not overrides or error.message.startswith("--set"):
            raise
        # The key may be one set on the command line, not the file's line named.
        said = ", ".join(f"--set {o}" for o in overrides)
        fix = f"{error.fix} (this run also has {said})".lstrip()
        raise ConfigFileError(path, error.message, where=error.where, fix=fix) from error


def parse_config(text: str, path: Path, overrides: Sequence[str] = ()) -> Config:
    """Validate ``text`` as the config at ``path``: the first problem found is the error raised."""
    doc, root = _read_doc(text, path, overrides)
    at = _Places(path, root)
    types, settings = _driver_types(doc, at)
    _check_model_named(doc, at.error)
    _check_driver_names(doc, at.error)
    _check_effect_signals(doc, at.error)
    _check_redundant_pairs(doc, at.error)
    _check_gain_schedule(doc, at.error)
    _check_probe_axes(doc, at.error)
    _check_addresses(doc, types, settings, at.error)
    check_overlaps(doc, types, settings, at.error, at.place)
    check_written(doc, types, settings, at.error)
    readback = output_readback(doc, types, settings, at.error)
    _check_load_access(doc, at.error)
    _check_telemetry_files(doc, path.parent, at.error)
    _check_hosts(doc, types, settings, path.parent, at.error)
    state_dir = paths.state_dir(doc.state.directory, path.parent)
    recorder_dir = None
    if doc.recorder.enabled:
        recorder_dir = paths.recorder_dir(doc.recorder.directory, state_dir, path.parent)
    return Config(
        path=path,
        doc=doc,
        model_path=None if doc.model is None else resolve_path(doc.model, path.parent),
        state_dir=state_dir,
        recorder_dir=recorder_dir,
        control_socket=paths.control_socket(doc.control_socket, state_dir, path.parent),
        driver_settings=settings,
        simulation=doc.simulation,
        readback=readback,
        whole_counts=whole_counts(doc, types, settings),
        mismatch_bit=status_mismatch_bit(doc, types, settings),
        model_fault_bit=status_model_fault_bit(doc, types, settings),
        root=root,
        overrides=tuple(overrides),
    )


@dataclass(frozen=True)
class _Places:
    """Errors placed in the config file: the line and key of a location."""

    path: Path
    root: NodeTree | None

    def error(self, location: tuple[str | int, ...], message: str, fix: str) -> ConfigFileError:
        return ConfigFileError(self.path, message, where=where(self.root, location), fix=fix)

    def place(self, location: tuple[str | int, ...]) -> str:
        """``line N (a.b.c)``: a place named in another place's error."""
        return where(self.root, location)

    def invalid(
        self,
        exc: ValidationError,
        prefix: tuple[str | int, ...],
        model: type[BaseModel] | None = None,
    ) -> ConfigFileError:
        return validation_error(exc, self.path, self.root, prefix, model)


def _read_doc(text: str, path: Path, overrides: Sequence[str] = ()) -> tuple[ConfigDoc, NodeTree]:
    """The YAML, of the supported schema, with ``overrides`` set, validated section by section."""
    data, root = parse_yaml(text, path, ConfigFileError)
    if overrides:
        data = apply_overrides(data, overrides, path)
    if not isinstance(data, dict) or data.get("schema") != SCHEMA:
        shown = data.get("schema") if isinstance(data, dict) else None
        raise ConfigFileError(
            path,
            f"unsupported or missing schema {shorten(shown)}",
            where="schema",
            fix=f"Start the file with 'schema: {SCHEMA}' (see config/compd.example.yaml)",
        )
    try:
        return ConfigDoc.model_validate(data), root
    except ValidationError as exc:
        raise validation_error(exc, path, root, (), ConfigDoc) from exc


def _driver_types(
    doc: ConfigDoc, at: _Places
) -> tuple[dict[str, DriverType], dict[str, BaseModel]]:
    """Each driver's type (by type name), imported, and its settings (by driver), validated by the type."""
    types: dict[str, DriverType] = {}
    settings: dict[str, BaseModel] = {}
    for name, driver in doc.drivers.items():
        try:
            types[driver.type] = load_driver_type(driver.type)
        except UnknownDriverError:
            raise at.error(
                ("drivers", name, "type"),
                f"unknown driver type {driver.type!r}",
                f"Use one of {driver_names()}",
            ) from None
        except DriverImportError as exc:
            raise at.error(
                ("drivers", name, "type"),
                str(exc),
                "Install the library it names (pip install compd reinstalls compd's own)",
            ) from exc
        try:
            settings[name] = types[driver.type].settings_model.model_validate(driver.settings)
        except ValidationError as exc:
            model = types[driver.type].settings_model
            raise at.invalid(exc, ("drivers", name, "settings"), model) from exc
    return types, settings


def _check_model_named(doc: ConfigDoc, error: ErrorAt) -> None:
    """Outputs need a model to compute their offsets; a config without outputs is a data logger."""
    if doc.outputs and doc.model is None:
        raise error(
            ("outputs",),
            f"outputs {sorted(doc.outputs)} need a model to compute their offsets, and 'model' "
            "is not set",
            "Name the model file ('model: base.yaml', written by compd fit), or remove "
            "'outputs' to run as a data logger that records the signals and writes nothing "
            "(compd record)",
        )


def _check_driver_names(doc: ConfigDoc, error: ErrorAt) -> None:
    """Every signal, output and the status name a driver defined under ``drivers``."""
    references: list[tuple[tuple[str | int, ...], str]] = [
        (("signals", n, "driver"), s.driver) for n, s in doc.signals.items()
    ]
    references += [(("outputs", n, "driver"), o.driver) for n, o in doc.outputs.items()]
    if doc.status is not None:
        references.append((("status", "driver"), doc.status.driver))
    references += [(("probes", "axes", a, "driver"), p.driver) for a, p in probe_axes(doc)]
    for location, driver_name in references:
        if driver_name not in doc.drivers:
            raise error(
                location,
                f"driver {driver_name!r} is not defined under 'drivers'",
                f"Define it or use one of {sorted(doc.drivers)}",
            )


def _check_effect_signals(doc: ConfigDoc, error: ErrorAt) -> None:
    """Every signal of the effect catalogue is defined under ``signals``."""
    for name, effect in doc.effects.items():
        for i, signal in enumerate(effect.signals):
            if signal not in doc.signals:
                raise error(
                    ("effects", name, "signals", i),
                    f"signal {signal!r} is not defined under 'signals'",
                    f"Define it or use one of {sorted(doc.signals)}",
                )


def _check_redundant_pairs(doc: ConfigDoc, error: ErrorAt) -> None:
    """Each partner (``redundant:``) is another signal of the same unit, partner of one signal
    only and naming none itself; a pair has a tolerance (a temperature's default, else given)."""
    partners: dict[str, str] = {}
    for name, signal in doc.signals.items():
        partner = signal.redundant
        if partner is None:
            if signal.redundant_tolerance is not None:
                raise error(
                    ("signals", name, "redundant_tolerance"),
                    "a tolerance for a redundant pair, and the signal names no partner",
                    "Name its second sensor ('redundant: <signal>'), or remove "
                    "'redundant_tolerance'",
                )
            continue
        where = ("signals", name, "redundant")
        if partner == name:
            raise error(
                where,
                f"signal {name!r} names itself as its partner",
                "Name the second sensor of the same point, another signal",
            )
        other = doc.signals.get(partner)
        if other is None:
            raise error(
                where,
                f"partner {partner!r} is not defined under 'signals'",
                f"Define the second sensor as a signal of its own, or use one of "
                f"{sorted(set(doc.signals) - {name})}",
            )
        if other.unit != signal.unit:
            raise error(
                where,
                f"partner {partner!r} is in {other.unit!r}, signal {name!r} in {signal.unit!r}: "
                "a pair reads one point in one unit",
                f"Give both the same unit (scale the partner's raw value to {signal.unit!r})",
            )
        if other.redundant is not None:
            raise error(
                where,
                f"partner {partner!r} names a partner of its own ({other.redundant!r})",
                "A pair is a model input and its second sensor: name the partner on the input only",
            )
        if partner in partners:
            raise error(
                where,
                f"{partner!r} is already the partner of {partners[partner]!r}",
                "Give each input a second sensor of its own",
            )
        partners[partner] = name
        if signal.redundant_tolerance is None and default_redundant_tolerance(signal.unit) is None:
            raise error(
                ("signals", name, "redundant"),
                f"a pair in {signal.unit!r} has no default tolerance (temperatures have one)",
                "Add 'redundant_tolerance:' in the signal's unit: how far the two may disagree "
                "beyond their usual difference",
            )


def _check_probe_axes(doc: ConfigDoc, error: ErrorAt) -> None:
    """Each probed axis is an output (a probe measures what an axis's offset compensates)."""
    if doc.probes is None:
        return
    for axis in doc.probes.axes:
        if axis not in doc.outputs:
            raise error(
                ("probes", "axes", axis),
                f"axis {axis!r} is not an output: a probe measures an axis compd compensates",
                f"Use one of {sorted(doc.outputs)}",
            )


def _check_gain_schedule(doc: ConfigDoc, error: ErrorAt) -> None:
    """The gain schedule's key is a defined signal, and no two of its rows overlap."""
    schedule = doc.gain_schedule
    if schedule is None:
        return
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


def _check_addresses(
    doc: ConfigDoc,
    types: Mapping[str, DriverType],
    settings: Mapping[str, BaseModel],
    error: ErrorAt,
) -> None:
    """Each address read or written is one its driver type accepts (:func:`compd.drivers.base.check_address`)."""
    for locations, writable in ((read_points(doc), False), (written_points(doc), True)):
        for location, driver_name, address in locations:
            kind = types[doc.drivers[driver_name].type]
            at = HookCall(location, driver_name, doc.drivers[driver_name].type, error)
            try:
                at.call(
                    f"whether {address!r} is an address",
                    partial(check_address, writable=writable, settings=settings[driver_name]),
                    kind,
                    address,
                    answers=(ValueError,),  # what is wrong with the address
                )
            except ValueError as exc:
                raise error(
                    location,
                    f"address {address!r} for driver {driver_name!r}: {exc}",
                    f"Write it {address_syntax(kind)}",
                ) from exc


def _check_load_access(doc: ConfigDoc, error: ErrorAt) -> None:
    """Every user and group named under ``load_access`` exists."""
    try:
        doc.load_access.ids()
    except KeyError as exc:
        raise error(
            ("load_access",), f"no such user or group: {exc}", "Give an existing name or a number"
        ) from exc


def _check_telemetry_files(doc: ConfigDoc, base_dir: Path, error: ErrorAt) -> None:
    """Every file the telemetry names exists and is readable; the password's text is never shown."""
    if doc.telemetry is None:
        return
    for key, name in doc.telemetry.files().items():
        file = resolve_path(name, base_dir)
        try:
            with file.open("rb"):
                pass
        except OSError as exc:
            raise error(
                ("telemetry", *key.split(".")),
                f"cannot read {file} ({exc.strerror or type(exc).__name__})",
                f"Give the path of a readable file (relative paths start at {base_dir})",
            ) from None


def _check_hosts(
    doc: ConfigDoc,
    types: Mapping[str, DriverType],
    settings: Mapping[str, BaseModel],
    base_dir: Path,
    error: ErrorAt,
) -> None:
    """Each driver's settings work on this host (files it names, see the ``check_host`` hook).

    Not for a simulated machine: the twin serves the controllers, and makes
    their certificates where missing.
    """
    if doc.simulation is not None:
        return
    for name, driver in doc.drivers.items():
        written = [address for _, d, address in written_points(doc) if d == name]
        at = HookCall(("drivers", name, "settings"), name, driver.type, error)
        problem = at.call(
            "whether its settings work on this host",
            partial(check_host, base_dir=base_dir, written=written),
            types[driver.type],
            settings[name],
        )
        if problem is not None:
            raise error(("drivers", name, "settings", *problem.keys), problem.message, problem.fix)


def validation_error(
    exc: ValidationError,
    path: Path,
    root: NodeTree | None,
    prefix: tuple[str | int, ...],
    model: type[BaseModel] | None = None,
) -> ConfigFileError:
    """The first of pydantic's complaints about the section at ``prefix``, placed in the file.

    With ``model`` (the section's), an unknown key's fix names the key meant
    and the keys allowed there.
    """
    # A misspelt key shows up as "unknown key" plus "missing key"; the
    # unknown one is the more useful to report.
    errors = sorted(exc.errors(), key=lambda e: e["type"] != "extra_forbidden")
    first = errors[0]
    location = (*prefix, *first["loc"])
    fix = FIXES.get(first["type"], "")
    if first["type"] == "extra_forbidden":
        hint = unknown_key_hint(model, first["loc"]) if model is not None else ""
        fix += f" ({hint})" if hint else " (see config/compd.example.yaml for every key)"
    return ConfigFileError(path, describe(first), where=where(root, location), fix=fix)
