"""From a compd config with a ``simulation`` section to a :class:`SimulatedMachine` and its servers.

Each driver instance of the config gets the simulated controller its type
connects to, built from the very settings the driver uses, serving exactly
the addresses the config reads and writes through it: the signals, the
offsets, the status word and heartbeat, and the probe registers of
``probes.axes`` (value, counter and touched-at served, echo and probe status
taken), the machine's probe cycles writing the former (:mod:`compd.sim.plc.probing`).
"""

from __future__ import annotations

import importlib
import re
from collections.abc import Callable

from compd.errors import ConfigFileError
from compd.service.config.docs import ConfigDoc
from compd.service.config.loading import Config
from compd.service.config.writepoints import probe_axes
from compd.sim.partners import PARTNER_SENSORS
from compd.sim.plc.machine import ServedAxis, ServedSignal, SimulatedMachine
from compd.sim.plc.probing import ServedProbe
from compd.sim.plc.server import PlcServer, PlcServerType
from compd.sim.plc.settings import SimulationDoc, simulation_of
from compd.sim.scenarios import SCENARIOS
from compd.sim.sensors import COLUMNS
from compd.sim.variants import VARIANTS

#: Driver type -> the simulated controller that serves it (module:class, imported when used).
SERVERS: dict[str, str] = {
    "modbus": "compd.sim.plc.modbus:ModbusPlcServer",
    "opcua": "compd.sim.plc.opcua:OpcUaPlcServer",
    "serial_sensor": "compd.sim.plc.serial:SerialPlcServer",
    "profibus_gateway": "compd.sim.plc.gateway:GatewayServer",
}
#: Driver types whose simulated controller runs probe cycles: it serves registers compd
#: reads beside those it writes (a serial scanner only answers with temperatures).
PROBE_SERVERS = frozenset({"modbus", "opcua", "profibus_gateway"})
#: What the machine's PLC can serve: every logged quantity of the twin. The
#: displacements are those of a test set-up (capacitive probes on a mandrel,
#: ISO 230-3) and are the thermal drift alone: the PLC takes off the offset it applied.
#: Beside them, the second sensors at the spindle bearings and in the air (:mod:`compd.sim.partners`).
SERVED_COLUMNS = tuple(c for c in COLUMNS if c != "time_s") + tuple(PARTNER_SENSORS)


def server_type(driver_type: str) -> PlcServerType:
    module, _, name = SERVERS[driver_type].partition(":")
    server: PlcServerType = getattr(importlib.import_module(module), name)
    return server


def build_machine(config: Config) -> SimulatedMachine:
    """The simulated machine ``config.simulation`` describes; ConfigFileError names what does not fit."""
    sim = simulation_of(config)
    doc = config.doc

    def error(where: str, message: str, fix: str) -> ConfigFileError:
        return ConfigFileError(config.path, message, where=where, fix=fix)

    if sim.scenario not in SCENARIOS:
        raise error(
            "simulation.scenario",
            f"unknown scenario {sim.scenario!r}",
            f"Use one of {sorted(SCENARIOS)}",
        )
    if sim.variant not in VARIANTS:
        raise error(
            "simulation.variant",
            f"unknown variant {sim.variant!r}",
            f"Use one of {sorted(VARIANTS)}",
        )
    for name, d in doc.drivers.items():
        if d.type not in SERVERS:
            raise error(
                f"drivers.{name}.type",
                f"the simulated machine has no controller for driver type {d.type!r}",
                f"Use one of {sorted(SERVERS)} in a config with a 'simulation' section",
            )
    signals = []
    for name, s in doc.signals.items():
        column = sim.signals.get(name, name)
        if column not in SERVED_COLUMNS:
            raise error(
                f"simulation.signals.{name}",
                f"signal {name!r} is not a quantity of the simulated machine",
                f"Map it to one of {list(SERVED_COLUMNS)} under 'simulation.signals'",
            )
        signals.append(ServedSignal(name, s.driver, s.address, column, s.scale, s.offset))
    unknown = sorted(set(sim.signals) - set(doc.signals))
    if unknown:
        raise error(
            "simulation.signals",
            f"{unknown} are not configured signals",
            "Remove them or define them under 'signals'",
        )
    if sim.join_at_s >= sim.hours * 3600:
        raise error(
            "simulation.join_at_s",
            f"compd would join at {sim.join_at_s:g} s, after the {sim.hours:g} h scenario ends",
            f"Give a time below {sim.hours * 3600:g} s, or more hours",
        )
    for i, fault in enumerate(sim.faults):
        if fault.signal is not None and fault.signal not in doc.signals:
            raise error(
                f"simulation.faults.{i}.signal",
                f"unknown signal {fault.signal!r}",
                f"Use one of {sorted(doc.signals)}",
            )
        if fault.driver is not None and fault.driver not in doc.drivers:
            raise error(
                f"simulation.faults.{i}.driver",
                f"unknown driver {fault.driver!r}",
                f"Use one of {sorted(doc.drivers)}",
            )
    axes = []
    for name, o in doc.outputs.items():
        match = re.fullmatch(r"disp_([xyz])_um", o.model_output)
        twin_axis = sim.axes.get(name) or (match.group(1) if match else None)
        if twin_axis is None:
            raise error(
                f"simulation.axes.{name}",
                f"cannot tell which machine axis output {name!r} ({o.model_output}) compensates",
                "Name it under 'simulation.axes', e.g. {" + name + ": z}",
            )
        axes.append(ServedAxis(name, o.driver, o.address, twin_axis, o.encoding.scale))
    status = (
        (doc.status.driver, doc.status.status_address, doc.status.heartbeat_address)
        if doc.status
        else None
    )
    probes = _probes(doc, sim, {a.name: a.twin_axis for a in axes}, error)
    servers: dict[str, PlcServer] = {}
    machine = SimulatedMachine(
        sim, signals=signals, axes=axes, servers=servers, status=status, probes=probes
    )
    for name, d in doc.drivers.items():
        inputs, outputs = served_addresses(doc, name)
        make = server_type(d.type)
        servers[name] = make(
            config.driver_settings[name],
            inputs=inputs,
            outputs=outputs,
            on_write=machine.on_write(name),
            base_dir=config.base_dir,
        )
    machine.servers.update(servers)
    return machine


def served_addresses(doc: ConfigDoc, driver: str) -> tuple[list[str], list[str]]:
    """What ``driver``'s simulated controller serves: (addresses compd reads, addresses it writes).

    Read: the signals and the probe registers the PLC writes (value, counter,
    touched-at); written: the offsets, the status word and heartbeat, each
    probe's echo and probe status word.
    """
    inputs = [s.address for s in doc.signals.values() if s.driver == driver]
    outputs = [o.address for o in doc.outputs.values() if o.driver == driver]
    if doc.status is not None and doc.status.driver == driver:
        outputs += [doc.status.status_address, doc.status.heartbeat_address]
    for _, p in probe_axes(doc):
        if p.driver == driver:
            inputs += [p.value_address, p.counter_address]
            inputs += [p.touched_at_address] if p.touched_at_address else []
            outputs += [p.echo_address] + ([p.status_address] if p.status_address else [])
    return inputs, outputs


def _probes(
    doc: ConfigDoc,
    sim: SimulationDoc,
    twin_axes: dict[str, str],
    error: Callable[[str, str, str], ConfigFileError],
) -> list[ServedProbe]:
    """The probe registers the PLC serves (``probes.axes``), checked against ``simulation.probes``."""
    probed = probe_axes(doc)
    if sim.probes.runs and not probed:
        raise error(
            "simulation.probes",
            "the simulated PLC is to run probe cycles, but the config has no probe registers "
            + ("(probes.enabled is false)" if doc.probes is not None else "(no 'probes' section)"),
            "Add 'probes.axes.<axis>' with the registers (see config/simulated.yaml), or remove "
            "'simulation.probes'",
        )
    for i, misprobe in enumerate(sim.probes.misprobes):
        if misprobe.axis is not None and misprobe.axis not in dict(probed):
            raise error(
                f"simulation.probes.misprobes.{i}.axis",
                f"axis {misprobe.axis!r} has no probe registers",
                f"Use one of {sorted(dict(probed))}, or leave 'axis' out (every probed axis)",
            )
    probes = []
    for axis, p in probed:
        kind = doc.drivers[p.driver].type
        if kind not in PROBE_SERVERS:
            raise error(
                f"probes.axes.{axis}.driver",
                f"driver {p.driver!r} (type {kind}) has no simulated controller that runs probe "
                "cycles",
                f"Put the probe registers on a driver of type {sorted(PROBE_SERVERS)}",
            )
        if p.value_scale == 0:
            raise error(
                f"probes.axes.{axis}.value_scale",
                "a value_scale of 0 makes every probe read 0 um",
                "Give the register's unit in um, e.g. 0.1 for tenths of a micrometre",
            )
        if sim.probes.when_due and p.status_address is None:
            raise error(
                f"probes.axes.{axis}.status_address",
                "simulation.probes.when_due runs a cycle when compd's probe status word asks, "
                f"but axis {axis!r} has no status_address",
                "Add a status_address for the axis, or set 'simulation.probes.every_h' instead",
            )
        probes.append(
            ServedProbe(
                axis=axis,
                twin_axis=twin_axes[axis],
                driver=p.driver,
                value_address=p.value_address,
                counter_address=p.counter_address,
                echo_address=p.echo_address,
                value_scale=p.value_scale,
                touched_at_address=p.touched_at_address,
                status_address=p.status_address,
                measures=doc.probes.measures if doc.probes is not None else "residue",
            )
        )
    return probes
