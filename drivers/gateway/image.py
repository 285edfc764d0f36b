"""The byte image of a Profibus DP gateway: address grammar and typed values at byte offsets.

A DP gateway shows compd two byte arrays: the *input* area (what the PLC
sends, read by compd) and the *output* area (what compd writes, received by
the PLC). A value lives at a byte offset in one of them::

    AREA:OFFSET[:TYPE][:byte=big|little][:word=big|little]
    AREA:OFFSET.BIT

    in:0:int16                 input bytes 0-1, int16, the driver's default orders
    in:4:float32:word=little   input bytes 4-7, float32, words swapped
    in:12.3                    bit 3 (value 8) of input byte 12, a bool
    out:0:int32                output bytes 0-3

``AREA`` is ``in`` (read only) or ``out`` (written by compd, and readable:
the driver's own output image). ``TYPE`` is one of
:data:`compd.drivers.points.POINT_TYPES` or a single byte, ``uint8`` /
``int8``; default ``uint16``. Orders not given in the address are the
driver's ``byte_order``/``word_order`` settings (Profibus images are
big-endian; CANopen PDOs little-endian; gateways that copy one into the
other differ).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache
from typing import Literal, cast

from compd.drivers.points import ORDERS, POINT_TYPES, Order, PointCodec, PointType
from compd.errors import DriverProtocolError

Area = Literal["in", "out"]
AREAS: tuple[str, ...] = ("in", "out")
#: Types of one byte, handled here since a register codec has no byte types.
BYTE_TYPES: dict[str, tuple[int, int]] = {"uint8": (0, 255), "int8": (-128, 127)}
IMAGE_TYPES: tuple[str, ...] = (*POINT_TYPES, *BYTE_TYPES)
MAX_AREA_BYTES = 65536

SYNTAX = (
    "as AREA:OFFSET[:TYPE][:byte=big|little][:word=big|little] or AREA:OFFSET.BIT, "
    "e.g. in:4:int32 or in:12.3 (AREA in|out, OFFSET in bytes from 0)"
)


@dataclass(frozen=True)
class ImageAddress:
    """One parsed address; orders ``None`` mean the driver's defaults."""

    area: Area
    offset: int
    bit: int | None
    type: str
    byte_order: Order | None
    word_order: Order | None

    @property
    def size_bytes(self) -> int:
        """Bytes the value occupies (a bit counts as its byte)."""
        if self.bit is not None or self.type in BYTE_TYPES:
            return 1
        size: int = PointCodec(type=cast(PointType, self.type)).size_bytes
        return size

    @property
    def end(self) -> int:
        """One past the last byte."""
        return self.offset + self.size_bytes


@cache
def parse_address(text: str) -> ImageAddress:
    """Parse an image address (see the module docstring); ValueError says what is wrong."""
    parts = [p.strip() for p in text.split(":")]
    if len(parts) < 2:
        raise ValueError(f"{text!r} is not AREA:OFFSET (e.g. 'in:4:int32' or 'in:12.3')")
    area, where, *rest = parts
    if area not in AREAS:
        raise ValueError(f"unknown area {area!r}; use 'in' (input area) or 'out' (output area)")
    offset_text, dot, bit_text = where.partition(".")
    if not offset_text.isdigit() or int(offset_text) >= MAX_AREA_BYTES:
        raise ValueError(f"byte offset {offset_text!r} must be an integer 0..{MAX_AREA_BYTES - 1}")
    bit: int | None = None
    if dot:
        if not (bit_text.isdigit() and int(bit_text) <= 7):
            raise ValueError(f"bit {bit_text!r} must be 0..7 (OFFSET.BIT, e.g. in:12.3)")
        bit = int(bit_text)
    kind = "bool" if dot else "uint16"
    options: dict[str, str] = {}
    for i, part in enumerate(rest):
        if "=" not in part:
            if i != 0:
                raise ValueError(f"the type must come right after the offset in {text!r}")
            kind = part
            continue
        key, _, value = part.partition("=")
        if key not in ("byte", "word") or key in options:
            raise ValueError(f"unknown or repeated option {key!r}; use byte= or word=")
        if value not in ORDERS:
            raise ValueError(f"{key}= must be 'big' or 'little', not {value!r}")
        options[key] = value
    if kind not in IMAGE_TYPES:
        raise ValueError(f"unknown type {kind!r}; use one of {IMAGE_TYPES}")
    if (kind == "bool") != (bit is not None):
        raise ValueError(
            "a bool is one bit: write it AREA:OFFSET.BIT (e.g. in:12.3)"
            if kind == "bool"
            else f"OFFSET.BIT is a bool, not {kind}: drop the '.{bit_text}' or the type"
        )
    if bit is not None and options:
        raise ValueError("a bit has no byte or word order")
    address = ImageAddress(
        cast(Area, area),
        int(offset_text),
        bit,
        kind,
        cast(Order | None, options.get("byte")),
        cast(Order | None, options.get("word")),
    )
    if address.end > MAX_AREA_BYTES:
        raise ValueError(f"{kind} at byte {offset_text} runs past the largest area")
    return address


class ImagePoint:
    """A parsed address with the driver's default orders applied: reads and writes an image."""

    __slots__ = ("address", "bit", "codec", "end", "offset")

    def __init__(self, address: ImageAddress, byte_order: Order, word_order: Order) -> None:
        self.address = address
        self.offset = address.offset
        self.end = address.end
        self.bit = address.bit
        self.codec: PointCodec | None = None
        if address.bit is None and address.type not in BYTE_TYPES:
            self.codec = PointCodec(
                type=cast(PointType, address.type),
                byte_order=address.byte_order or byte_order,
                word_order=address.word_order or word_order,
            )

    def read(self, image: bytes | bytearray) -> float:
        """The raw value in ``image`` (which must reach ``end``)."""
        if self.codec is not None:
            value: float = self.codec.decode_bytes(bytes(image[self.offset : self.end]))
            return value
        byte = image[self.offset]
        if self.bit is not None:
            return float((byte >> self.bit) & 1)
        if self.address.type == "int8" and byte > 127:
            return float(byte - 256)
        return float(byte)

    def encode(self, value: float) -> bytes:
        """Bytes for ``value`` (not for bits); DriverProtocolError if it does not fit, never wrapped."""
        if self.codec is not None:
            data: bytes = self.codec.encode_bytes(value)
            return data
        low, high = BYTE_TYPES[self.address.type]
        rounded = round(value) if value == value and abs(value) != float("inf") else None
        if rounded is None or not low <= rounded <= high:
            raise DriverProtocolError(f"{value} does not fit {self.address.type} [{low}, {high}]")
        return (rounded & 0xFF).to_bytes(1, "big")  # two's complement of an in-range int8

    def write(self, image: bytearray, value: float) -> None:
        """Put ``value`` into ``image``, range-checked first (nothing changes on error)."""
        if self.bit is None:
            image[self.offset : self.end] = self.encode(value)
            return
        if value not in (0.0, 1.0):
            raise DriverProtocolError(f"a bit takes 0 or 1, not {value}")
        mask = 1 << self.bit
        image[self.offset] = (image[self.offset] | mask) if value else (image[self.offset] & ~mask)


def frame_of(offset: int, frame_bytes: int = 8) -> int:
    """Index of the CAN frame (PDO) that carries image byte ``offset``."""
    return offset // frame_bytes


def check_in_area(address: ImageAddress, *, input_bytes: int, output_bytes: int) -> None:
    """ValueError if the value does not lie inside its area."""
    size = input_bytes if address.area == "in" else output_bytes
    if address.end > size:
        raise ValueError(
            f"bytes {address.offset}..{address.end - 1} lie outside the {address.area} area "
            f"of {size} bytes; enlarge {address.area}put_bytes or fix the offset"
        )


def check_one_frame(address: ImageAddress, frame_bytes: int = 8) -> None:
    """ValueError if a multi-byte value straddles two CAN frames (two gateway cycles)."""
    if frame_of(address.offset, frame_bytes) != frame_of(address.end - 1, frame_bytes):
        first = frame_of(address.offset, frame_bytes)
        start = first * frame_bytes
        raise ValueError(
            f"{address.type} at byte {address.offset} straddles frames {first} (bytes "
            f"{start}..{start + frame_bytes - 1}) and {first + 1}: its parts may come from "
            f"different gateway cycles. Place it inside one {frame_bytes}-byte frame, "
            f"e.g. at byte {start + frame_bytes}"
        )
