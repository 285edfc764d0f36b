"""No written value overlaps another value: one check over every driver entry that reaches a device.

``check-config`` (and ``compd run``) compare the cells every point of a
config occupies -- registers, image bits, nodes, each with the endpoint it
lives on (:func:`compd.drivers.base.write_footprint`,
:mod:`compd.drivers.endpoints`) -- across all driver entries, since two
entries may reach one PLC (the same host and port, serial line or CAN bus):

- a written value (an axis offset, the status word, the heartbeat) may share
  no cell with another written value, nor with a value read as a signal;
  two signals may read one cell;
- a driver entry that rewrites an area whole whenever it writes (a Profibus
  gateway's output area, :func:`compd.drivers.base.write_area`) owns that
  area: no other entry may read or write in it, and two entries writing one
  gateway are refused even where their values are apart;
- Modbus unit ids: behind Modbus TCP many servers ignore the unit id, so a
  value reaches every unit id of its host and port unless the driver entries
  say ``unit_ids: separate`` (a gateway to a serial bus, routing each id to
  its own device); on a serial line a unit id is an address on the wire
  (the broadcast id 0 reaches every one);
- OPC UA: a NodeId and a browse path naming the same node are told apart
  only by the server, so on a server compd writes to, every address (of every
  entry, read or written) must name its node one way
  (:func:`compd.drivers.base.naming`); one way, the same spelling is the
  same node. compd refuses the mix here rather than resolving nodes when it
  connects, so that a config that passes ``check-config`` never faults later
  for it;
- a serial line is one driver entry's alone (a Modbus RTU master, a serial
  sensor scanner: :func:`compd.drivers.base.exclusive_line`): two entries
  on one port would interleave requests and take each other's replies.

Each refusal names both places in the file and the fix.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable, Mapping
from dataclasses import dataclass
from functools import partial
from typing import TYPE_CHECKING

from pydantic import BaseModel

from compd.service.config.writepoints import ErrorAt, HookCall, read_points, written_points

if TYPE_CHECKING:
    from compd.drivers.base import DriverType
    from compd.service.config.docs import ConfigDoc

Location = tuple[str | int, ...]
#: ``line N (a.b.c)`` of a place in the config file.
PlaceOf = Callable[[Location], str]
_FIX = (
    "Give every written value its own registers, bytes or node on the device, counting every "
    "driver entry that reaches it (or use one driver entry per device)"
)
_UNIT_IDS = (
    "; unit ids on one Modbus TCP host:port count as one device unless each driver entry "
    "says 'unit_ids: separate' (a server routing each unit id to its own device)"
)


@dataclass(frozen=True)
class _Use:
    """A point of the config (or a driver entry's whole write area, ``address`` None)."""

    location: Location
    driver: str
    address: str | None
    written: bool


def check_overlaps(
    doc: ConfigDoc,
    types: Mapping[str, DriverType],
    settings: Mapping[str, BaseModel],
    error: ErrorAt,
    place: PlaceOf,
) -> None:
    """Raise for a written value sharing a cell with another value or a driver entry's write area."""
    from compd.drivers.base import naming, write_area, write_footprint

    def kind(driver: str) -> DriverType:
        return types[doc.drivers[driver].type]

    _check_exclusive_lines(doc, kind, settings, error, place)

    uses = [_Use(location, d, address, False) for location, d, address in read_points(doc)]
    uses += [_Use(location, d, address, True) for location, d, address in written_points(doc)]
    writers = dict.fromkeys(use.driver for use in uses if use.written)
    uses += [_Use(("drivers", d), d, None, True) for d in writers]
    claims: dict[Hashable, tuple[_Use, ...]] = {}
    namings: dict[Hashable, list[tuple[_Use, Hashable]]] = {}
    for use in uses:
        at = HookCall(use.location, use.driver, doc.drivers[use.driver].type, error)
        if use.address is None:
            cells = at.call("its write area", write_area, kind(use.driver), settings[use.driver])
        else:
            what = f"the cells of {use.address!r}"
            cells = at.call(
                what,
                partial(write_footprint, instance=use.driver),
                kind(use.driver),
                use.address,
                settings[use.driver],
            )
            named = at.call(
                f"how {use.address!r} names its node",
                naming,
                kind(use.driver),
                use.address,
                settings[use.driver],
            )
            if named is not None:
                for endpoint in {cell[0] for cell in cells}:
                    namings.setdefault(endpoint, []).append((use, named))
        # Set operations: a Modbus TCP value spans every unit id, hundreds of cells.
        shared = cells & claims.keys()
        for cell in sorted(shared, key=repr):
            clash = next((other for other in claims[cell] if _clash(use, other)), None)
            if clash is not None:
                raise _overlap(use, clash, cell[0], error, place)
            claims[cell] += (use,)
        claims.update(dict.fromkeys(cells - shared, (use,)))
    for endpoint, namings_there in namings.items():
        _check_one_naming(endpoint, namings_there, error, place)


def _check_exclusive_lines(
    doc: ConfigDoc,
    kind: Callable[[str], DriverType],
    settings: Mapping[str, BaseModel],
    error: ErrorAt,
    place: PlaceOf,
) -> None:
    """Raise for a second driver entry on a line one entry holds alone (a serial port)."""
    from compd.drivers.base import exclusive_line

    holders: dict[Hashable, str] = {}
    for driver in doc.drivers:
        at = HookCall(("drivers", driver), driver, doc.drivers[driver].type, error)
        line = at.call("which line it holds", exclusive_line, kind(driver), settings[driver])
        if line is None:
            continue
        first = holders.setdefault(line, driver)
        if first != driver:
            raise error(
                ("drivers", driver),
                f"driver {driver!r} opens {_describe(line)}, as driver {first!r} at "
                f"{place(('drivers', first))} does: two entries on one serial line interleave "
                "their requests on the wire and take each other's replies",
                "Reach every device on a serial line through one driver entry (Modbus RTU: "
                "give each signal its device id in the address, e.g. 'holding:100:int16:device=2'), "
                "or connect the second device to another port",
            )


def _clash(use: _Use, other: _Use) -> bool:
    """Two uses of one cell clash where either writes, except a driver entry's own area and values."""
    if not (use.written or other.written):
        return False
    area = use.address is None or other.address is None
    return not (area and use.driver == other.driver)


def _overlap(
    use: _Use, other: _Use, endpoint: Hashable, error: ErrorAt, place: PlaceOf
) -> Exception:
    """The refusal of ``use`` for a cell ``other`` (earlier in the file) holds."""
    verb = "written" if other.written else "read"
    reach = "" if use.driver == other.driver else f": both drivers reach {_describe(endpoint)}"
    devices = use.driver != other.driver or any(
        "device=" in (u.address or "") for u in (use, other)
    )
    units = _UNIT_IDS if _modbus_tcp(endpoint) and devices else ""
    if use.address is None:  # areas come last: ``other`` is a point or another entry's area
        inside = (
            f"so does driver {other.driver!r} at {place(other.location)}"
            if other.address is None
            else f"{other.address!r} on driver {other.driver!r} is {verb} inside it at "
            f"{place(other.location)}"
        )
        return error(
            use.location,
            f"driver {use.driver!r} rewrites its whole output area on every write, and "
            f"{inside}{reach}{units}",
            "Reach a gateway through one driver entry, and keep other drivers' values out of its "
            "output area",
        )
    if (other.driver, other.address) == (use.driver, use.address):
        what = "is already "
    else:
        what = f"overlaps {other.address!r} on driver {other.driver!r}, "
    return error(
        use.location,
        f"address {use.address!r} on driver {use.driver!r} {what}{verb} at "
        f"{place(other.location)}{reach}{units}",
        _FIX,
    )


def _check_one_naming(
    endpoint: Hashable, named: list[tuple[_Use, Hashable]], error: ErrorAt, place: PlaceOf
) -> None:
    """Where compd writes on ``endpoint``, every address names its node the same way."""
    if not any(use.written for use, _ in named):
        return
    first, way = named[0]
    for use, other_way in named[1:]:
        if other_way != way:
            raise error(
                use.location,
                f"address {use.address!r} on driver {use.driver!r} names its node as "
                f"{other_way}, {first.address!r} at {place(first.location)} as {way}: compd "
                f"writes to {_describe(endpoint)} and cannot tell before connecting whether they "
                "name one node",
                f"Name every node on this server as {way} (as a client such as UaExpert shows "
                f"it) or every one as {other_way}",
            )


def _describe(endpoint: Hashable) -> str:
    """``modbus loopback:502``, ``serial /dev/ttyUSB0``, ``can virtual:vcan0`` for a message."""
    if not isinstance(endpoint, tuple) or not endpoint:
        return repr(endpoint)
    kind, *rest = endpoint
    if len(rest) == 2:
        return f"{kind} {rest[0]}:{rest[1]}"
    return " ".join(map(str, endpoint))


def _modbus_tcp(endpoint: Hashable) -> bool:
    return isinstance(endpoint, tuple) and len(endpoint) == 3 and endpoint[0] == "modbus"
