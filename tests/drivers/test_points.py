"""The point codec: exact round trips for every type and order, known layouts, and range errors."""

from __future__ import annotations

import math
import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from compd.drivers.points import ORDERS, POINT_TYPES, PointCodec
from compd.errors import DriverProtocolError

INT_RANGES = {
    "bool": (0, 1),
    "int16": (-(2**15), 2**15 - 1),
    "uint16": (0, 2**16 - 1),
    "int32": (-(2**31), 2**31 - 1),
    "uint32": (0, 2**32 - 1),
}
LAYOUTS = [(t, b, w) for t in POINT_TYPES for b in ORDERS for w in ORDERS]


def raw_values(kind: str) -> st.SearchStrategy[float]:
    if kind in INT_RANGES:
        low, high = INT_RANGES[kind]
        return st.integers(low, high).map(float)
    width = 32 if kind == "float32" else 64
    return st.floats(allow_nan=False, allow_infinity=False, width=width)


@pytest.mark.parametrize(("kind", "byte_order", "word_order"), LAYOUTS)
@settings(max_examples=40, deadline=None)
@given(data=st.data())
def test_register_and_byte_round_trip(kind, byte_order, word_order, data):
    """Every representable raw value survives encode then decode, as registers and as bytes."""
    codec = PointCodec(kind, byte_order, word_order)
    value = data.draw(raw_values(kind))
    registers = codec.encode_registers(value)
    assert len(registers) == codec.words and all(0 <= r <= 0xFFFF for r in registers)
    assert codec.decode_registers(registers) == value
    assert codec.decode_bytes(codec.encode_bytes(value)) == value


@settings(max_examples=60, deadline=None)
@given(
    raw=st.integers(-(2**31), 2**31 - 1),
    scale=st.sampled_from([0.1, 0.01, 2.0, -0.5]),
    offset=st.sampled_from([0.0, -40.0, 273.15]),
)
def test_scaled_int32_round_trip(raw, scale, offset):
    """value = raw * scale + offset decodes, and encoding that value gives back the same raw."""
    codec = PointCodec("int32", scale=scale, offset=offset)
    value = codec.decode_registers(codec.encode_registers(raw * scale + offset))
    assert value == pytest.approx(raw * scale + offset, rel=1e-12, abs=1e-9 * abs(scale))
    assert codec.raw_for(value) == raw


def test_orders_follow_the_abcd_notation():
    """0x11223344 as uint32 is ABCD, CDAB, BADC and DCBA on the wire for the four order pairs."""
    expected = {
        ("big", "big"): [0x1122, 0x3344],
        ("big", "little"): [0x3344, 0x1122],
        ("little", "big"): [0x2211, 0x4433],
        ("little", "little"): [0x4433, 0x2211],
    }
    for (byte_order, word_order), registers in expected.items():
        codec = PointCodec("uint32", byte_order, word_order)
        assert codec.encode_registers(0x11223344) == registers
    little = PointCodec("float64", "little", "little").encode_bytes(1.5)
    assert little == struct.pack("<d", 1.5)  # both little: plain little-endian (CANopen)


def test_engineering_units():
    """An int16 in 0.01 degC reads -12.34; an offset of 12.3 um written as int32 in 0.1 um is 123."""
    assert PointCodec("int16", scale=0.01).decode_registers([0xFB2E]) == pytest.approx(-12.34)
    assert PointCodec("int32", scale=0.1).encode_registers(12.3) == [0, 123]


@pytest.mark.parametrize(
    ("kind", "value"),
    [
        ("int16", 32768.0),
        ("int16", -32769.0),
        ("uint16", -1.0),
        ("uint16", 65536.0),
        ("int32", 2.0**31),
        ("uint32", 2.0**32),
        ("bool", 2.0),
        ("float32", 1e39),
        ("float64", math.nan),
        ("int32", math.inf),
    ],
)
def test_out_of_range_is_refused_never_wrapped(kind, value):
    """A value that does not fit its type (or is not finite) raises DriverProtocolError."""
    with pytest.raises(DriverProtocolError):
        PointCodec(kind).encode_registers(value)


def test_scaled_range_error_names_the_raw_value():
    """With scale 0.1 um, 3276.8 um (raw 32768) does not fit int16 and the message says so."""
    with pytest.raises(DriverProtocolError, match=r"raw 32768 .*int16"):
        PointCodec("int16", scale=0.1).encode_registers(3276.8)


def test_wrong_lengths_and_bad_settings():
    """Decoding the wrong number of registers or bytes is a protocol error; bad settings a ValueError."""
    with pytest.raises(DriverProtocolError, match="2 register"):
        PointCodec("int32").decode_registers([1])
    with pytest.raises(DriverProtocolError, match="8 bytes"):
        PointCodec("float64").decode_bytes(b"\0" * 4)
    with pytest.raises(ValueError, match="unknown point type"):
        PointCodec("int8")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="scale"):
        PointCodec("int16", scale=0.0)


def test_bool_reads_any_non_zero_word_as_true():
    """A bool point reads a non-zero register as 1.0 and zero as 0.0."""
    codec = PointCodec("bool")
    assert [codec.decode_registers([r]) for r in (0, 1, 0x8000)] == [0.0, 1.0, 1.0]
