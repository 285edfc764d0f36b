"""Driver types by name: compd's own, and those other packages install.

A config names a driver type (``drivers.<name>.type``); only then is its
module imported, so a daemon speaking Modbus never loads asyncua, python-can
or the simulator. Third-party packages add a type through the
``compd.drivers`` entry-point group, without touching compd::

    [project.entry-points."compd.drivers"]
    mybus = "mypackage.driver:MyBusDriver"
"""

from __future__ import annotations

import importlib
from functools import cache

from compd.drivers.base import DriverType
from compd.extras import missing_extra

#: Entry-point group for third-party drivers.
ENTRY_POINT_GROUP = "compd.drivers"

#: compd's own driver types: config name -> ``module:class``, imported on first use.
BUILTIN: dict[str, str] = {
    "linuxcnc": "compd.drivers.linuxcnc:LinuxCncDriver",
    "modbus": "compd.drivers.modbus.driver:ModbusDriver",
    "opcua": "compd.drivers.opcua.driver:OpcUaDriver",
    "profibus_gateway": "compd.drivers.gateway.driver:GatewayDriver",
    "serial_sensor": "compd.drivers.serial_sensor:SerialSensorDriver",
    "simulated": "compd.drivers.simulated:SimulatedDriver",
}


class UnknownDriverError(LookupError):
    """No built-in or installed driver type has this name."""


class DriverImportError(ImportError):
    """A driver type's module cannot be imported (a library it needs is missing or broken)."""


def driver_names() -> list[str]:
    """Every driver type a config may name, without importing any of them."""
    from importlib import metadata  # the installed packages' list: only when asked

    installed = {entry.name for entry in metadata.entry_points(group=ENTRY_POINT_GROUP)}
    return sorted(BUILTIN.keys() | installed)


@cache
def load_driver_type(name: str) -> DriverType:
    """The driver class a config's ``type: NAME`` means, its module imported now.

    Built-in names win over an installed package's entry point of the same name.
    """
    if name in BUILTIN:
        module, _, attribute = BUILTIN[name].partition(":")
        try:
            kind: DriverType = getattr(importlib.import_module(module), attribute)
        except ImportError as exc:
            raise DriverImportError(
                f"driver type {name!r} cannot be imported: {exc}{_extra_note(exc)}"
            ) from exc
        return kind
    from importlib import metadata  # a daemon of built-in drivers never reads it

    for entry in metadata.entry_points(group=ENTRY_POINT_GROUP, name=name):
        try:
            loaded: DriverType = entry.load()
        except ImportError as exc:
            raise DriverImportError(
                f"driver type {name!r} ({entry.value}) cannot be imported: {exc}{_extra_note(exc)}"
            ) from exc
        return loaded
    raise UnknownDriverError(name)


def _extra_note(exc: ImportError) -> str:
    """Where the missing library is an extra's (asyncua, the ``simulated`` driver's pandas): its install line."""
    missing = missing_extra(exc)
    return "" if missing is None else f" (install it: {missing.install})"
