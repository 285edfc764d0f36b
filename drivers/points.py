"""The point codec: typed values <-> 16-bit registers or a byte image, for every byte-level driver.

Field buses carry numbers as bytes; a PLC programmer decides per value how
many, in what order and in what unit. One :class:`PointCodec` describes one
such value so that Modbus, gateway and other byte-level drivers share one
tested conversion instead of each writing its own ``struct`` calls.

Types: ``bool``, ``int16``, ``uint16``, ``int32``, ``uint32``, ``float32``,
``float64`` (1, 1, 1, 2, 2, 2, 4 sixteen-bit words; ``bool`` is one word
read as ``raw != 0`` and written as 0 or 1).

Orders, with the usual letter notation for a 32-bit value whose most
significant byte is A::

    byte_order  word_order   bytes on the wire   also called
    big         big          A B C D             ABCD, big-endian (Modbus default, Profibus)
    big         little       C D A B             CDAB, "word swap"
    little      big          B A D C             BADC, "byte swap"
    little      little       D C B A             DCBA, little-endian (CANopen)

``word_order`` orders the 16-bit words (most significant first for
``big``); ``byte_order`` orders the two bytes inside each word. 64-bit
values follow the same rules over four words.

Scaling to engineering units::

    value = raw * scale + offset                (decode)
    raw   = (value - offset) / scale            (encode; rounded to the nearest integer for integer types)

Encoding never wraps: a raw value outside the type's range (or NaN, or a
float beyond float32's range) raises :class:`~compd.errors.DriverProtocolError`
before anything is sent.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal, get_args

from compd.errors import DriverProtocolError

PointType = Literal["bool", "int16", "uint16", "int32", "uint32", "float32", "float64"]
Order = Literal["big", "little"]

POINT_TYPES: tuple[str, ...] = get_args(PointType)
ORDERS: tuple[str, ...] = get_args(Order)

# struct format (big-endian) per type; bool travels as one unsigned word.
_FORMATS: dict[str, str] = {
    "bool": ">H",
    "int16": ">h",
    "uint16": ">H",
    "int32": ">i",
    "uint32": ">I",
    "float32": ">f",
    "float64": ">d",
}
# Inclusive raw range of the integer types.
INT_RANGES: dict[str, tuple[int, int]] = {
    "bool": (0, 1),
    "int16": (-(2**15), 2**15 - 1),
    "uint16": (0, 2**16 - 1),
    "int32": (-(2**31), 2**31 - 1),
    "uint32": (0, 2**32 - 1),
}
_FLOAT32_MAX = struct.unpack(">f", b"\x7f\x7f\xff\xff")[0]


@dataclass(frozen=True)
class PointCodec:
    """How one value is laid out in words/bytes and scaled; see the module docstring."""

    type: PointType = "uint16"
    byte_order: Order = "big"
    word_order: Order = "big"
    scale: float = 1.0
    offset: float = 0.0

    def __post_init__(self) -> None:
        if self.type not in POINT_TYPES:
            raise ValueError(f"unknown point type {self.type!r}; use one of {POINT_TYPES}")
        for name in ("byte_order", "word_order"):
            if getattr(self, name) not in ORDERS:
                raise ValueError(f"{name} must be 'big' or 'little', not {getattr(self, name)!r}")
        if not (math.isfinite(self.scale) and self.scale != 0 and math.isfinite(self.offset)):
            raise ValueError("scale must be finite and non-zero, offset finite")

    @property
    def size_bytes(self) -> int:
        """Bytes the value occupies (2, 4 or 8)."""
        return struct.calcsize(_FORMATS[self.type])

    @property
    def words(self) -> int:
        """16-bit registers the value occupies (1, 2 or 4)."""
        return self.size_bytes // 2

    # -- byte image -------------------------------------------------------

    def decode_bytes(self, data: bytes) -> float:
        """Engineering value from ``size_bytes`` bytes laid out in this point's orders."""
        if len(data) != self.size_bytes:
            raise DriverProtocolError(f"{self.type} needs {self.size_bytes} bytes, got {len(data)}")
        (raw,) = struct.unpack(_FORMATS[self.type], self.reorder(bytes(data)))
        if self.type == "bool":
            raw = 1 if raw else 0
        return float(raw) * self.scale + self.offset

    def encode_bytes(self, value: float) -> bytes:
        """Bytes for engineering ``value``, range-checked (never wrapped)."""
        raw = self.raw_for(value)
        return self.reorder(struct.pack(_FORMATS[self.type], raw))

    # -- 16-bit registers (a register is one big-endian word on the Modbus wire) --

    def decode_registers(self, registers: Sequence[int]) -> float:
        """Engineering value from ``words`` registers, each 0..65535, in wire order."""
        if len(registers) != self.words:
            raise DriverProtocolError(
                f"{self.type} needs {self.words} register(s), got {len(registers)}"
            )
        try:
            data = b"".join(r.to_bytes(2, "big") for r in registers)
        except OverflowError as exc:
            raise DriverProtocolError(f"register value out of 0..65535 in {registers}") from exc
        return self.decode_bytes(data)

    def encode_registers(self, value: float) -> list[int]:
        """Registers (wire order) for engineering ``value``, range-checked (never wrapped)."""
        data = self.encode_bytes(value)
        return [int.from_bytes(data[i : i + 2], "big") for i in range(0, len(data), 2)]

    # -- scaling and range ------------------------------------------------

    def raw_for(self, value: float) -> int | float:
        """``(value - offset) / scale``, rounded for integer types; DriverProtocolError if it does not fit."""
        if not math.isfinite(value):
            raise DriverProtocolError(f"cannot write {value} as {self.type}: not a finite number")
        raw = (value - self.offset) / self.scale
        if self.type == "float64":
            return raw
        if self.type == "float32":
            if abs(raw) > _FLOAT32_MAX:
                raise DriverProtocolError(
                    f"{value} (raw {raw:g}) is outside the float32 range ±{_FLOAT32_MAX:g}"
                )
            return raw
        if not math.isfinite(raw):
            raise DriverProtocolError(f"{value} scales to {raw} for {self.type}")
        rounded = round(raw)
        low, high = INT_RANGES[self.type]
        if not low <= rounded <= high:
            raise DriverProtocolError(
                f"{value} (raw {rounded} at scale {self.scale:g}, offset {self.offset:g}) "
                f"does not fit {self.type} [{low}, {high}]"
            )
        return rounded

    def reorder(self, data: bytes) -> bytes:
        """Convert between big-endian bytes and this point's layout (an involution).

        Public for servers that must lay out a value the codec refuses to
        encode (the simulated gateway serves a PLC's NaN or infinity).
        """
        words = [data[i : i + 2] for i in range(0, len(data), 2)]
        if self.word_order == "little":
            words.reverse()
        if self.byte_order == "little":
            words = [w[::-1] for w in words]
        return b"".join(words)
