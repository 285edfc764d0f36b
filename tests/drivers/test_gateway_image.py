"""The gateway's byte-image addresses: grammar, byte types, bits, default orders, and frame straddling."""

from __future__ import annotations

import pytest

from compd.drivers.gateway.image import ImagePoint, check_one_frame, parse_address
from compd.errors import DriverProtocolError


def point(text: str, byte_order: str = "big", word_order: str = "big") -> ImagePoint:
    return ImagePoint(parse_address(text), byte_order, word_order)  # type: ignore[arg-type]


def test_default_orders_come_from_the_driver_and_the_address_overrides_them():
    """An address without byte=/word= takes the driver's orders; one with them keeps its own."""
    image = bytearray(8)
    point("in:0:int32", "little", "little").write(image, 0x01020304)
    assert bytes(image[:4]) == b"\x04\x03\x02\x01"
    point("in:4:int32:byte=big:word=big", "little", "little").write(image, 0x01020304)
    assert bytes(image[4:]) == b"\x01\x02\x03\x04"


def test_bytes_and_bits():
    """int8/uint8 take one byte, range-checked; a bit is set and cleared without touching its neighbours."""
    image = bytearray(2)
    point("out:0:int8").write(image, -5)
    assert image[0] == 0xFB and point("out:0:int8").read(image) == -5.0
    with pytest.raises(DriverProtocolError, match=r"does not fit uint8 \[0, 255\]"):
        point("out:1:uint8").write(image, 256)
    image[1] = 0b1010_0000
    point("out:1.0").write(image, 1)
    point("out:1.7").write(image, 0)
    assert image[1] == 0b0010_0001
    with pytest.raises(DriverProtocolError, match="0 or 1"):
        point("out:1.0").write(image, 0.5)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("inp:0", "unknown area 'inp'"),
        ("in", "is not AREA:OFFSET"),
        ("in:-1", "must be an integer"),
        ("in:3.8", "bit '8' must be 0..7"),
        ("in:3.1:int16", "OFFSET.BIT is a bool"),
        ("in:3:bool", "a bool is one bit"),
        ("in:0:word=little:int32", "the type must come right after"),
        ("in:0:int32:word=middle", "must be 'big' or 'little'"),
        ("in:65534:int32", "runs past"),
    ],
)
def test_bad_addresses_say_what_is_wrong(text, message):
    """Each malformed address raises ValueError naming the problem."""
    with pytest.raises(ValueError, match=message):
        parse_address(text)


def test_straddling_is_rejected_inside_a_frame_is_not():
    """A multi-byte value crossing an 8-byte boundary is rejected with the byte to move it to."""
    check_one_frame(parse_address("in:4:int32"))
    check_one_frame(parse_address("in:8:float64"))
    with pytest.raises(ValueError, match=r"e\.g\. at byte 16"):
        check_one_frame(parse_address("in:15:int16"))
