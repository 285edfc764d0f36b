"""Modbus addresses: ``TABLE:ADDRESS[:TYPE][:byte=..][:word=..][:device=N]`` parsed once into a point.

The grammar is documented with the driver (:mod:`compd.drivers.modbus.driver`); the
simulated PLC's Modbus server lays out its registers with the same parser,
so both sides agree on every address by construction.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
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


#: What each table holds, as manuals name it.
_NAMES = {
    "coil": "coil",
    "discrete": "discrete input",
    "input": "input register",
    "holding": "holding register",
}
#: Modicon reference prefixes: 0xxxx coils, 1xxxx discrete inputs, 3xxxx input, 4xxxx holding registers.
_MODICON: dict[str, Table] = {"0": "coil", "1": "discrete", "3": "input", "4": "holding"}


def modicon(text: str) -> tuple[str, str] | None:
    """A Modicon reference's ``TABLE:ADDRESS`` (0-based, on the wire) and a note of the translation; None: not one.

    ``40101`` (5 digits: registers 1-9999) and ``400101`` (6 digits: 1-65536)
    name holding register 101 counted from 1, which is address 100 on the
    wire. The rest of the address (``40101:int32``) is kept.
    """
    number, sep, rest = text.strip().partition(":")
    if not (number.isdigit() and len(number) in (5, 6) and number[0] in _MODICON):
        return None
    register = int(number[1:])
    if not 1 <= register <= (9999 if len(number) == 5 else 65536):
        return None
    table = _MODICON[number[0]]
    wire = f"{table}:{register - 1}" + (sep + rest)
    return wire, f"{number} is Modicon numbering (from 1): {table}:{register - 1} on the wire"


def translation_note(text: str) -> str | None:
    """How an address in Modicon or 1-based numbering was read, for the user to confirm; None: as written.

    A table's ADDRESS that reads as a Modicon reference (``input:30001``,
    ``input:40101``) is taken as written, on the wire, and this says what it
    would be if it was meant as one: the hint a bare ``40101`` gets.
    """
    if (found := modicon(text)) is not None:
        return found[1]
    parts = [p.strip() for p in text.split(":")]
    if "base=1" in parts[2:] and len(parts) >= 2 and parts[1].isdigit():
        return f"{parts[0]}:{parts[1]} with base=1 (from 1): {parts[0]}:{int(parts[1]) - 1} on the wire"
    if len(parts) >= 2 and parts[0] in TABLES and (meant := modicon(parts[1])) is not None:
        table, number = parts[0], parts[1]
        rest = "".join(f":{p}" for p in parts[2:])
        wire = meant[0] + rest
        meant_table = wire.split(":")[0]
        where = (
            f"{_NAMES[meant_table]} {int(number[1:])}, not {_NAMES[table]} {number}"
            if meant_table != table
            else f"{_NAMES[table]} {int(number[1:])} counted from 1"
        )
        return (
            f"{table}:{number} is read as {table} address {number} on the wire; {number} looks "
            f"like Modicon numbering ({where}): if so, write {number}{rest} or {wire}"
        )
    return None


def word_order_given(text: str) -> bool:
    """Whether the address names its word order (``word=big`` or ``word=little``)."""
    return any(p.strip().startswith("word=") for p in text.split(":")[1:])


def word_order_hint(text: str, words: Sequence[int]) -> str:
    """What a person should check about registers read at ``text``: an open word order; "" if nothing.

    A value of two or four registers at an address without ``word=`` is read
    big-endian by word (ABCD); a PLC that stores the low word first (CDAB)
    gives another number from the same registers. When the two orders read
    differently, both are shown; when every register is 0, both read 0 and
    the order cannot be told from this value at all.
    """
    point = parse_address(text)
    if point.table in BIT_TABLES or point.codec.words < 2 or word_order_given(text):
        return ""
    other = replace(point.codec, word_order="little")
    if not any(words):
        return (
            "0 in either word order: the order cannot be told from this value; read it "
            "again when it is not 0, then set word=big (ABCD) or word=little (CDAB)"
        )
    mine, theirs = point.codec.decode_registers(words), other.decode_registers(words)
    if mine == theirs:
        return ""
    return (
        f"no word= given: {mine:.6g} as word=big (ABCD); word=little (CDAB) would read "
        f"{theirs:.6g}; set word= to the PLC's order"
    )


@cache
def parse_address(text: str) -> ModbusPoint:
    """Parse ``TABLE:ADDRESS[:TYPE][:byte=..][:word=..][:device=N][:base=1]``; ValueError says what is wrong.

    Also a Modicon reference (``40101``, ``300001:float32``), and with
    ``base=1`` an ADDRESS counted from 1 as manuals do (``holding:101:base=1``
    is ``holding:100``); :func:`translation_note` says how either was read.
    """
    if (found := modicon(text)) is not None:
        text = found[0]
    parts = [p.strip() for p in text.split(":")]
    if "base=1" in parts[2:]:
        parts.remove("base=1")
        if parts[1].isdigit():
            if int(parts[1]) == 0:
                raise ValueError("with base=1 addresses count from 1: 0 is not one")
            parts[1] = str(int(parts[1]) - 1)
    if len(parts) < 2:
        raise ValueError(
            f"{text!r} is not TABLE:ADDRESS (e.g. 'holding:100:int32') or a Modicon "
            "reference (e.g. 40101 for holding register 101 counted from 1)"
        )
    table, number, *rest = parts
    if table not in TABLES:
        raise ValueError(f"unknown Modbus table {table!r}; use one of {TABLES}")
    if not number.isdigit() or not 0 <= int(number) <= 65535:
        raise ValueError(
            f"address {number!r} must be an integer 0..65535 (0-based, on the wire; "
            "add :base=1 for numbers counted from 1, or write a Modicon reference such as 40101)"
        )
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
            raise ValueError(
                f"unknown or repeated option {key!r}; use byte=, word=, device=, base=1"
            )
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
