"""The driver interface: how compd reads signals from and writes offsets to a machine.

A driver is the smallest thing that can talk to one bus or controller: four
coroutines (:class:`Driver`), a pydantic settings model it owns, and a
constructor taking those settings. The loop never sees a protocol library's
exceptions: drivers raise only compd's :class:`~compd.errors.DriverError`
family (timeout / disconnected / protocol), and the loop reconnects.

Driver types are looked up by name in :data:`DRIVERS`, a plain dict, plus
the ``compd.drivers`` entry-point group so a third-party package can ship a
driver without touching compd::

    [project.entry-points."compd.drivers"]
    mybus = "mypackage.driver:MyBusDriver"

Two optional class-level hooks tell the config checks and the service what a
driver type's addresses mean; a type without them gets the cautious answer
(:func:`write_footprint`, :func:`reads_back`):

``footprint(address, settings) -> frozenset``
    the cells (registers, bytes or bits, nodes) a written value occupies,
    so that ``check-config`` refuses two written values sharing one;
``raw_range(address, settings) -> tuple[int, int] | None``
    the whole numbers an integer point holds (``None``: a float, or not known
    before connecting), so that ``check-config`` refuses an offset, status
    word or heartbeat that cannot fit, and counts its resolution;
``reads_back(settings) -> bool``
    whether ``read()`` of a written address returns what the device holds
    *now* (after a PLC restart that cleared it, say), not what this driver
    last sent; the service then re-seeds each offset's slew limit from it.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable, Mapping, Sequence
from importlib import metadata
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

from compd.drivers.gateway import GatewayDriver
from compd.drivers.linuxcnc import LinuxCncDriver
from compd.drivers.modbus import ModbusDriver
from compd.drivers.opcua import OpcUaDriver
from compd.drivers.serial_sensor import SerialSensorDriver
from compd.drivers.simulated import SimulatedDriver
from pydantic import BaseModel

#: Entry-point group for third-party drivers.
ENTRY_POINT_GROUP = "compd.drivers"


@runtime_checkable
class Driver(Protocol):
    """One connection to a machine. Addresses (``points``) are driver-specific strings."""

    async def open(self) -> None:
        """Connect; raise :class:`~compd.errors.DriverError` if the device cannot be reached."""

    async def read(self, points: Sequence[str]) -> dict[str, float]:
        """Current value per address; a missing key means no new value for that address."""
        ...

    async def write(self, values: Mapping[str, float]) -> None:
        """Write every value (already encoded: scaled and rounded as the device expects)."""

    async def close(self) -> None:
        """Release the connection; never raises."""


class DriverType(Protocol):
    """A driver class: its settings schema and a constructor taking validated settings.

    ``now`` is the service's clock (seconds, monotonic); ``base_dir`` is the
    directory of the config file, for settings naming files.
    """

    settings_model: type[BaseModel]

    def __call__(self, settings: Any, *, now: Callable[[], float], base_dir: Path) -> Driver: ...


#: Built-in driver types by the name a config's ``drivers.<name>.type`` gives.
DRIVERS: dict[str, DriverType] = {
    "linuxcnc": LinuxCncDriver,
    "modbus": ModbusDriver,
    "opcua": OpcUaDriver,
    "profibus_gateway": GatewayDriver,
    "serial_sensor": SerialSensorDriver,
    "simulated": SimulatedDriver,
}


def driver_types() -> dict[str, DriverType]:
    """Built-in drivers and those installed under the ``compd.drivers`` entry-point group."""
    found = dict(DRIVERS)
    for entry in metadata.entry_points(group=ENTRY_POINT_GROUP):
        found.setdefault(entry.name, entry.load())
    return found


def write_footprint(kind: DriverType, address: str, settings: BaseModel) -> frozenset[Hashable]:
    """The cells a value written at ``address`` occupies; without the hook, the address itself."""
    footprint = getattr(kind, "footprint", None)
    if footprint is None:
        return frozenset({address})
    cells: frozenset[Hashable] = footprint(address, settings)
    return cells


def reads_back(kind: DriverType, settings: BaseModel) -> bool:
    """Whether reading a written address returns the device's value; without the hook, no."""
    hook = getattr(kind, "reads_back", None)
    return bool(hook(settings)) if hook is not None else False


def write_range(kind: DriverType, address: str, settings: BaseModel) -> tuple[int, int] | None:
    """The whole numbers an integer point holds; ``None`` for a float point or without the hook."""
    hook = getattr(kind, "raw_range", None)
    if hook is None:
        return None
    bounds: tuple[int, int] | None = hook(address, settings)
    return bounds
