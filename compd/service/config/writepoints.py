"""The values compd writes to a machine, checked together: no overlap, a fine enough encoding, readback.

The rules ``check-config`` (and ``compd run``) apply to the written points
of a config -- the axis offsets, the status word and the heartbeat:

- no two may share a register, byte, bit or node of a device, nor share one
  with a signal, through one driver entry or several
  (:mod:`compd.service.config.overlaps`): a status word at ``holding:101`` inside
  an int32 offset at ``holding:100`` makes the PLC read garbage for both;
- an integer-encoded offset (or one written to an integer register) must
  resolve one slew step: with a resolution ``1 / scale`` um coarser than
  ``max_rate_um_per_s * period_s``, the offset moves in steps of a whole
  count, larger than the slew limit allows;
- where a driver knows a point's integer range (:func:`compd.drivers.base.write_range`),
  ``±max_offset_um`` must fit it, and the status word's signal bits and the
  heartbeat's highest count must fit theirs: a value that does not fit fails
  the whole write, offsets, status and heartbeat alike (the readback-mismatch
  bit is used only where it fits, :func:`status_mismatch_bit`);
- ``readback: true`` needs a driver that can read back what the device holds
  (:func:`compd.drivers.base.reads_back`); left out, readback is on wherever
  the driver can.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from pydantic import BaseModel

from compd.errors import ConfigFileError
from compd.service.loop.safety import HEARTBEAT_MODULO, SIGNAL_BIT0, mismatch_bit, model_fault_bit

if TYPE_CHECKING:
    from compd.drivers.base import DriverType
    from compd.service.config.docs import ConfigDoc, ProbeAxisDoc

#: Builds the config error for a place: ``error(location, message, fix)``.
ErrorAt = Callable[[tuple[str | int, ...], str, str], ConfigFileError]


@dataclass(frozen=True)
class HookCall:
    """A driver type's config-time hook called for one place of the config.

    A third-party driver's hook may raise anything; ``check-config`` then
    names the entry, its type and what it raised instead of a traceback.
    """

    location: tuple[str | int, ...]
    driver: str
    type_name: str
    error: ErrorAt

    def call(
        self,
        what: str,
        hook: Callable[..., Any],
        *args: Any,
        answers: tuple[type[Exception], ...] = (),
    ) -> Any:
        """``hook(*args)``; an exception of ``answers`` is the hook's answer and passes as it is."""
        try:
            return hook(*args)
        except answers:
            raise
        except Exception as exc:
            raise self.error(
                self.location,
                f"driver {self.driver!r} (type {self.type_name!r}) could not tell {what}: "
                f"{type(exc).__name__}: {exc}",
                "A defect of the driver type: report it to its maintainer with this message",
            ) from exc


#: The whole numbers a point (driver, address) holds; ``None``: a float or not known.
Bounds = Callable[[str, str], tuple[int, int] | None]


def written_points(doc: ConfigDoc) -> list[tuple[tuple[str | int, ...], str, str]]:
    """``(location, driver, address)`` of every value compd writes, in config order."""
    written: list[tuple[tuple[str | int, ...], str, str]] = [
        (("outputs", n, "address"), o.driver, o.address) for n, o in doc.outputs.items()
    ]
    if doc.status is not None:
        written += [
            (("status", "status_address"), doc.status.driver, doc.status.status_address),
            (("status", "heartbeat_address"), doc.status.driver, doc.status.heartbeat_address),
        ]
    for axis, probe in probe_axes(doc):
        written.append((("probes", "axes", axis, "echo_address"), probe.driver, probe.echo_address))
        if probe.status_address is not None:
            where = ("probes", "axes", axis, "status_address")
            written.append((where, probe.driver, probe.status_address))
    return written


def probe_axes(doc: ConfigDoc) -> list[tuple[str, ProbeAxisDoc]]:
    """The axes whose probes the PLC reports through registers (``probes.axes``), when probes are on."""
    if doc.probes is None or not doc.probes.enabled:
        return []
    return [(axis, probe) for axis, probe in doc.probes.axes.items() if probe is not None]


def read_points(doc: ConfigDoc) -> list[tuple[tuple[str | int, ...], str, str]]:
    """``(location, driver, address)`` of every value compd reads: the signals, the probes' registers."""
    read: list[tuple[tuple[str | int, ...], str, str]] = [
        (("signals", n, "address"), s.driver, s.address) for n, s in doc.signals.items()
    ]
    for axis, probe in probe_axes(doc):
        for field in ("value_address", "counter_address", "touched_at_address"):
            address = getattr(probe, field)
            if address is not None:
                read.append((("probes", "axes", axis, field), probe.driver, address))
    return read


def check_written(
    doc: ConfigDoc,
    types: Mapping[str, DriverType],
    settings: Mapping[str, BaseModel],
    error: ErrorAt,
) -> None:
    """Raise for an offset coarser than a slew step, or a value that cannot fit its point."""
    from compd.drivers.base import write_range

    def bounds(driver: str, address: str) -> tuple[int, int] | None:
        kind = doc.drivers[driver].type
        at = HookCall(("drivers", driver), driver, kind, error)
        found: tuple[int, int] | None = at.call(
            f"the whole numbers {address!r} holds",
            write_range,
            types[kind],
            address,
            settings[driver],
        )
        return found

    _check_offsets(doc, bounds, error)
    if doc.status is not None:
        _check_status(doc, bounds, error)


def _check_offsets(doc: ConfigDoc, bounds_of: Bounds, error: ErrorAt) -> None:
    """Each offset fits its point at ``±max_offset_um``, and a count resolves a slew step."""
    for name, output in doc.outputs.items():
        encoding = output.encoding
        bounds = bounds_of(output.driver, output.address)
        step_um = output.max_rate_um_per_s * doc.period_s
        resolution_um = 1.0 / encoding.scale
        if (encoding.type == "int" or bounds is not None) and resolution_um > step_um * (1 + 1e-9):
            counts = "an integer count" if encoding.type == "int" else "a count of the register"
            raise error(
                ("outputs", name, "encoding", "scale"),
                f"{counts} of {resolution_um:g} um (scale {encoding.scale:g}) is coarser than one "
                f"slew step of {step_um:g} um (max_rate_um_per_s x period_s): the offset would "
                "move in steps larger than the slew limit",
                f"Use scale >= {1.0 / step_um:g} (a finer unit on the PLC) or raise "
                "max_rate_um_per_s",
            )
        if bounds is None:
            continue
        low, high = bounds
        reach = output.max_offset_um * encoding.scale
        if round(-reach) < low or round(reach) > high:
            raise error(
                ("outputs", name, "address"),
                f"{output.address!r} holds {low}..{high}, but ±max_offset_um ({output.max_offset_um:g}"
                f" um) at scale {encoding.scale:g} is ±{reach:g}: such an offset could not be written",
                "Use a wider (signed) type, a smaller encoding.scale or a smaller max_offset_um",
            )


def _check_status(doc: ConfigDoc, bounds_of: Bounds, error: ErrorAt) -> None:
    """The status word's highest bit and the heartbeat's highest count fit their points."""
    status = doc.status
    assert status is not None
    top_bit = SIGNAL_BIT0 + len(doc.signals) - 1
    needs = (
        ("status_address", status.status_address, (1 << (top_bit + 1)) - 1, f"bits 0..{top_bit}"),
        ("heartbeat_address", status.heartbeat_address, HEARTBEAT_MODULO - 1, "0..32767"),
    )
    for key, address, largest, what in needs:
        bounds = bounds_of(status.driver, address)
        if bounds is not None and largest > bounds[1]:
            raise error(
                ("status", key),
                f"{address!r} holds {bounds[0]}..{bounds[1]}, but it must carry {what} "
                f"(up to {largest}) for {len(doc.signals)} signals",
                "Use a wider unsigned type (uint16 up to 8 signals, uint32 beyond)",
            )


def output_readback(
    doc: ConfigDoc,
    types: Mapping[str, DriverType],
    settings: Mapping[str, BaseModel],
    error: ErrorAt,
) -> dict[str, bool]:
    """Whether each axis reads its offset back: as configured, else wherever the driver can."""
    from compd.drivers.base import reads_back

    readback = {}
    for name, output in doc.outputs.items():
        kind = doc.drivers[output.driver].type
        at = HookCall(("outputs", name), output.driver, kind, error)
        can = at.call("whether it reads back", reads_back, types[kind], settings[output.driver])
        if output.readback and not can:
            raise error(
                ("outputs", name, "readback"),
                f"driver {output.driver!r} (type {kind}) cannot read back what the device holds",
                "Remove 'readback: true' (the offset then resumes from the saved state, else 0)",
            )
        readback[name] = can if output.readback is None else output.readback
    return readback


def whole_counts(
    doc: ConfigDoc, types: Mapping[str, DriverType], settings: Mapping[str, BaseModel]
) -> dict[str, bool]:
    """Whether each axis's point holds whole counts: an int encoding, or an integer register."""
    from compd.drivers.base import write_range

    return {
        name: output.encoding.type == "int"
        or write_range(
            types[doc.drivers[output.driver].type], output.address, settings[output.driver]
        )
        is not None
        for name, output in doc.outputs.items()
    }


def status_mismatch_bit(
    doc: ConfigDoc, types: Mapping[str, DriverType], settings: Mapping[str, BaseModel]
) -> int | None:
    """The status word's readback-mismatch bit (:func:`compd.service.loop.safety.mismatch_bit`), if its point holds it.

    A status word at a 16-bit register with 8 signals has no bit left: the
    mismatch then shows in the log and the counters only, never in a value
    the register cannot take (which would fail the whole write).
    """
    return _held_bit(doc, types, settings, mismatch_bit(len(doc.signals)))


def status_model_fault_bit(
    doc: ConfigDoc, types: Mapping[str, DriverType], settings: Mapping[str, BaseModel]
) -> int | None:
    """The status word's model-fault bit (:func:`compd.service.loop.safety.model_fault_bit`), if its point holds it."""
    return _held_bit(doc, types, settings, model_fault_bit(len(doc.signals)))


def _held_bit(
    doc: ConfigDoc,
    types: Mapping[str, DriverType],
    settings: Mapping[str, BaseModel],
    bit: int | None,
) -> int | None:
    from compd.drivers.base import write_range

    if doc.status is None or bit is None:
        return None
    kind = types[doc.drivers[doc.status.driver].type]
    bounds = write_range(kind, doc.status.status_address, settings[doc.status.driver])
    return bit if bounds is None or (1 << (bit + 1)) - 1 <= bounds[1] else None
