"""Modbus addresses: ``TABLE:ADDRESS[:TYPE][:byte=..][:word=..][:device=N]`` parsed once into a point.

The grammar is documented with the driver (:mod:`compd.drivers.modbus`); the
simulated PLC's Modbus server lays out its registers with the same parser,
so both sides agree on every address by construction.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache
from typing import Literal, cast

from compd.drivers.points import ORDERS, POINT_TYPES, Order, PointCodec, PointType

Table = Literal["holding", "input", "coil", "discrete"]
#: The tables an address may name.
TABLES: tuple[str, ...] = ("holding", "input", "coil", "discrete")
#: The tables compd may write to.
WRITABLE_TABLES = ("holding", "coil")
#: The tables of single bits (their type is always bool).
BIT_TABLES = ("coil", "discrete")


@dataclass(frozen=True)
class ModbusPoint:
    """One parsed address: where the value lives and how it is encoded."""

    table: Table
    address: int
    codec: PointCodec
    device_id: int | None  # None: the driver's default

    @property
    def count(self) -> int:
        """Registers (or bits) the value spans."""
        return 1 if self.table in BIT_TABLES else self.codec.words


@cache
def parse_address(text: str) -> ModbusPoint:
    """Parse ``TABLE:ADDRESS[:TYPE][:byte=..][:word=..][:device=N]``; ValueError says what is wrong."""
    parts = [p.strip() for p in text.split(":")]
    if len(parts) < 2:
        raise ValueError(f"{text!r} is not TABLE:ADDRESS (e.g. 'holding:100:int32')")
    table, number, *rest = parts
    if table not in TABLES:
        raise ValueError(f"unknown Modbus table {table!r}; use one of {TABLES}")
    if not number.isdigit() or not 0 <= int(number) <= 65535:
        raise ValueError(f"address {number!r} must be an integer 0..65535 (0-based, on the wire)")
    kind = "bool" if table in BIT_TABLES else "uint16"
    options: dict[str, str] = {}
    for i, part in enumerate(rest):
        if "=" not in part:
            if i != 0:
                raise ValueError(f"the type must come right after the address in {text!r}")
            kind = part
            continue
        key, _, value = part.partition("=")
        if key not in ("byte", "word", "device") or key in options:
            raise ValueError(f"unknown or repeated option {key!r}; use byte=, word=, device=")
        options[key] = value
    if kind not in POINT_TYPES:
        raise ValueError(f"unknown type {kind!r}; use one of {POINT_TYPES}")
    if table in BIT_TABLES and kind != "bool":
        raise ValueError(f"a {table} is a single bit: its type can only be bool")
    for key in ("byte", "word"):
        if options.get(key, "big") not in ORDERS:
            raise ValueError(f"{key}= must be 'big' or 'little'")
    device = options.get("device")
    if device is not None and not (device.isdigit() and int(device) <= 247):
        raise ValueError("device= must be an integer 0..247")
    # PointCodec checks type and orders again; the messages above are the friendlier ones.
    codec = PointCodec(
        type=cast(PointType, kind),
        byte_order=cast(Order, options.get("byte", "big")),
        word_order=cast(Order, options.get("word", "big")),
    )
    if int(number) + codec.words > 65536:
        raise ValueError(f"{kind} at {number} runs past register 65535")
    return ModbusPoint(
        cast(Table, table), int(number), codec, None if device is None else int(device)
    )
