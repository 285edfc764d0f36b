"""Values between OPC UA variants and compd's floats: read any numeric node, write with the node's type.

OPC UA values are typed by the server, so unlike Modbus there is no byte
codec: a read turns Boolean / integer / Float / Double into ``float``, and a
write sends the value as the node's own variant type. Integer types get
``round(value)`` checked against the type's range (``Int16``: -32768..32767);
a value that does not fit raises :class:`~compd.errors.DriverProtocolError`
before anything is sent, never a wrapped number.
"""

from __future__ import annotations

import math
from typing import Any

from asyncua import ua

from compd.errors import DriverProtocolError

#: Inclusive range of each integer variant type; writes outside it are refused.
INT_RANGES: dict[ua.VariantType, tuple[int, int]] = {
    ua.VariantType.SByte: (-(2**7), 2**7 - 1),
    ua.VariantType.Byte: (0, 2**8 - 1),
    ua.VariantType.Int16: (-(2**15), 2**15 - 1),
    ua.VariantType.UInt16: (0, 2**16 - 1),
    ua.VariantType.Int32: (-(2**31), 2**31 - 1),
    ua.VariantType.UInt32: (0, 2**32 - 1),
    ua.VariantType.Int64: (-(2**63), 2**63 - 1),
    ua.VariantType.UInt64: (0, 2**64 - 1),
}
#: Largest finite IEEE-754 single, for Float nodes.
FLOAT32_MAX = 3.4028234663852886e38
NUMERIC_TYPES = {ua.VariantType.Boolean, ua.VariantType.Float, ua.VariantType.Double, *INT_RANGES}


def variant_type(data_type: ua.NodeId) -> ua.VariantType | None:
    """Builtin variant type of a DataType NodeId (ns=0, ids 1..25 are the builtin types)."""
    if data_type.NamespaceIndex != 0 or not isinstance(data_type.Identifier, int):
        return None
    try:
        return ua.VariantType(data_type.Identifier)
    except ValueError:
        return None


def to_float(point: str, value: Any) -> float:
    """A read value as float: Boolean is 0/1, integers exact up to 2**53; other types are errors."""
    if isinstance(value, bool | int | float):
        return float(value)
    raise DriverProtocolError(
        f"OPC UA variable {point!r} returned {type(value).__name__} {value!r}, not a number"
    )


def to_variant(point: str, value: float, vtype: ua.VariantType) -> ua.Variant:
    """``value`` as a Variant of the node's type; integers rounded and range-checked, never wrapped.

    NaN and infinities are refused for every type: a machine never gets one.
    """
    if not math.isfinite(value):
        raise DriverProtocolError(
            f"value {value} for OPC UA variable {point!r} is not finite; nothing written"
        )
    if vtype in INT_RANGES:
        low, high = INT_RANGES[vtype]
        if not low <= round(value) <= high:
            raise DriverProtocolError(
                f"value {value} for OPC UA variable {point!r} does not fit {vtype.name} "
                f"({low}..{high}); nothing written"
            )
        return ua.Variant(round(value), vtype)
    if vtype == ua.VariantType.Boolean:
        if value not in (0.0, 1.0):
            raise DriverProtocolError(
                f"value {value} for Boolean OPC UA variable {point!r} is not 0 or 1; nothing written"
            )
        return ua.Variant(bool(value), vtype)
    if vtype == ua.VariantType.Float and abs(value) > FLOAT32_MAX:
        raise DriverProtocolError(
            f"value {value} for OPC UA variable {point!r} does not fit Float; nothing written"
        )
    return ua.Variant(float(value), vtype)
