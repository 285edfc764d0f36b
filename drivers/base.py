"""The driver interface: how compd reads signals from and writes offsets to a machine.

A driver is the smallest thing that can talk to one bus or controller: four
coroutines (:class:`Driver`), a pydantic settings model it owns, and a
constructor taking those settings. The loop never sees a protocol library's
exceptions: drivers raise only compd's :class:`~compd.errors.DriverError`
family (timeout / disconnected / protocol), and the loop reconnects.

This module imports no driver: :mod:`compd.drivers.registry` finds a driver
type by the name a config gives and imports its module only then, so a
daemon on Modbus never loads asyncua, python-can or the simulator.

Optional class-level hooks tell the config checks and the service what a
driver type's addresses mean; a type without them gets the cautious answer
(:func:`check_address`, :func:`write_footprint`, :func:`reads_back`):

``validate_address(address, *, writable, settings=None)``
    raises ValueError naming what is wrong with one address (its grammar;
    with ``settings``, also what only the instance knows, e.g. area sizes);
``address_syntax: str``
    the grammar, shown as the fix when ``validate_address`` refuses;

``footprint(address, settings) -> frozenset``
    the cells (registers, bytes or bits, nodes) a value occupies, each a
    tuple starting with the endpoint it lives on
    (:mod:`compd.drivers.endpoints`: host and port, serial line, CAN bus),
    so that ``check-config`` refuses a written value sharing a cell with
    another value, read or written, of any driver entry reaching that device;
``write_area(settings) -> frozenset``
    the cells an instance rewrites whole whenever it writes at all (a
    gateway's output area), which no other driver entry may use;
``exclusive_line(settings) -> Hashable | None``
    a line the instance opens and speaks on alone (a serial port: two
    programs' requests interleave on the wire and each takes the other's
    replies), so that ``check-config`` refuses a second driver entry on it;
``naming(address, settings) -> Hashable``
    how an address names its node where only the device can tell whether
    two namings meet (an OPC UA NodeId and a browse path): on an endpoint
    compd writes to, every address must be named one way;
``raw_range(address, settings) -> tuple[int, int] | None``
    the whole numbers an integer point holds (``None``: a float, or not known
    before connecting), so that ``check-config`` refuses an offset, status
    word or heartbeat that cannot fit, and counts its resolution;
``reads_back(settings) -> bool``
    whether ``read()`` of a written address returns what the device holds
    *now* (after a PLC restart that cleared it, say), not what this driver
    last sent; the service then re-seeds each offset's slew limit from it.
``address_note(address) -> str | None``
    how an address in another numbering was read (a Modbus ``40101`` is
    ``holding:100``), which ``check-config`` shows;
``check_host(settings, *, base_dir, written) -> HostProblem | None``
    the first setting that cannot work on this host, found without
    connecting (a certificate or INI file that is not there, an axis the
    INI gives no offset budget), so that ``check-config`` refuses it
    instead of the driver at every reconnect; ``written`` are the
    addresses the config writes, ``base_dir`` the config's folder.

One optional instance hook serves commissioning (``compd read``, ``compd probe``):

``async read_raw(points) -> dict[str, RawReading]``
    what the device returned for each address before it became the float
    ``read()`` gives (registers, image bytes, a node's variant, a reply's
    field), read in one batch as ``read()`` would; without it,
    :func:`read_raw` shows the float itself.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

from pydantic import BaseModel

#: Shown as the fix for a refused address when a driver type has no ``address_syntax``.
DEFAULT_ADDRESS_SYNTAX = "as config/compd.example.yaml shows"


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


@dataclass(frozen=True)
class RawReading:
    """One address as the device gave it: ``raw`` for people, ``value`` as ``read()`` gives it.

    ``value`` is ``None`` when the device answered without a usable value
    (a bad OPC UA quality, a scanner value outside the sensor's range);
    ``note`` then says why. ``hint`` is what a person should check about a
    value that came (a Modbus ``int32`` without ``word=`` whose registers read
    otherwise in the other word order, or are all 0).
    """

    raw: str
    value: float | None
    note: str = ""
    hint: str = ""


@runtime_checkable
class RawReader(Protocol):
    """The optional ``read_raw`` hook, declared: a driver that has it has it so."""

    async def read_raw(self, points: Sequence[str]) -> dict[str, RawReading]: ...


async def read_raw(driver: Driver, points: Sequence[str]) -> dict[str, RawReading]:
    """Each address's raw reading through the driver's hook; without it, ``read()``'s float."""
    if isinstance(driver, RawReader):
        return await driver.read_raw(points)
    values = await driver.read(points)
    return {point: RawReading(repr(value), value) for point, value in values.items()}


class AddressHooks(Protocol):
    """The optional address hooks, declared: a driver type that has them has them so."""

    address_syntax: str

    @staticmethod
    def validate_address(address: str, *, writable: bool, settings: Any = None) -> None: ...


def check_address(
    kind: DriverType, address: str, *, writable: bool, settings: BaseModel | None = None
) -> None:
    """Run the type's ``validate_address`` hook, if it has one (ValueError names the fault)."""
    hook = getattr(kind, "validate_address", None)
    if hook is not None:
        hook(address, writable=writable, settings=settings)


def address_syntax(kind: DriverType) -> str:
    """The type's address grammar, for the fix of a refused address."""
    return str(getattr(kind, "address_syntax", DEFAULT_ADDRESS_SYNTAX))


def write_footprint(
    kind: DriverType, address: str, settings: BaseModel, *, instance: str
) -> frozenset[tuple[Hashable, ...]]:
    """The cells a value at ``address`` occupies; without the hook, the address on this instance alone."""
    footprint = getattr(kind, "footprint", None)
    if footprint is None:
        return frozenset({(("instance", instance), address)})
    cells: frozenset[tuple[Hashable, ...]] = footprint(address, settings)
    return cells


def write_area(kind: DriverType, settings: BaseModel) -> frozenset[tuple[Hashable, ...]]:
    """The cells an instance rewrites whole on every write; without the hook, none."""
    hook = getattr(kind, "write_area", None)
    return frozenset() if hook is None else frozenset(hook(settings))


def exclusive_line(kind: DriverType, settings: BaseModel) -> Hashable | None:
    """The line an instance holds open alone (a serial port); without the hook, none."""
    hook = getattr(kind, "exclusive_line", None)
    return None if hook is None else hook(settings)


def naming(kind: DriverType, address: str, settings: BaseModel) -> Hashable:
    """How ``address`` names its node, where namings may not be compared offline; without the hook, None."""
    hook = getattr(kind, "naming", None)
    return None if hook is None else hook(address, settings)


def reads_back(kind: DriverType, settings: BaseModel) -> bool:
    """Whether reading a written address returns the device's value; without the hook, no."""
    hook = getattr(kind, "reads_back", None)
    return bool(hook(settings)) if hook is not None else False


@dataclass(frozen=True)
class HostProblem:
    """A setting that cannot work on this host: where (keys under ``settings``), what, and the fix."""

    keys: tuple[str, ...]
    message: str
    fix: str


def check_host(
    kind: DriverType, settings: BaseModel, *, base_dir: Path, written: Sequence[str]
) -> HostProblem | None:
    """Run the type's ``check_host`` hook, if it has one."""
    hook = getattr(kind, "check_host", None)
    if hook is None:
        return None
    problem: HostProblem | None = hook(settings, base_dir=base_dir, written=written)
    return problem


def address_note(kind: DriverType, address: str) -> str | None:
    """How the type read an address written in another numbering (``address_note`` hook), or None."""
    hook = getattr(kind, "address_note", None)
    note: str | None = None if hook is None else hook(address)
    return note


def write_range(kind: DriverType, address: str, settings: BaseModel) -> tuple[int, int] | None:
    """The whole numbers an integer point holds; ``None`` for a float point or without the hook."""
    hook = getattr(kind, "raw_range", None)
    if hook is None:
        return None
    bounds: tuple[int, int] | None = hook(address, settings)
    return bounds
