"""From a compd config with a ``simulation`` section to a :class:`SimulatedMachine` and its servers.

Each driver instance of the config gets the simulated controller its type
connects to, built from the very settings the driver uses, serving exactly
the addresses the config reads and writes through it.
"""

from __future__ import annotations

import importlib
import re

from compd.errors import ConfigFileError
from compd.service.config.loading import Config
from compd.sim.plc.machine import ServedAxis, ServedSignal, SimulatedMachine
from compd.sim.plc.server import PlcServer, PlcServerType
from compd.sim.plc.settings import simulation_of
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
#: What the machine's PLC can serve: every logged quantity of the twin. The
#: displacements are those of a test set-up (capacitive probes on a mandrel,
#: ISO 230-3) and are the thermal drift alone: the PLC takes off the offset it applied.
SERVED_COLUMNS = tuple(c for c in COLUMNS if c != "time_s")


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
    servers: dict[str, PlcServer] = {}
    machine = SimulatedMachine(sim, signals=signals, axes=axes, servers=servers, status=status)
    for name, d in doc.drivers.items():
        outputs = [o.address for o in doc.outputs.values() if o.driver == name]
        if doc.status is not None and doc.status.driver == name:
            outputs += [doc.status.status_address, doc.status.heartbeat_address]
        make = server_type(d.type)
        servers[name] = make(
            config.driver_settings[name],
            inputs=[s.address for s in doc.signals.values() if s.driver == name],
            outputs=outputs,
            on_write=machine.on_write(name),
            base_dir=config.base_dir,
        )
    machine.servers.update(servers)
    return machine
