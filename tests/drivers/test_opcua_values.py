"""OPC UA values: numbers and Booleans read as floats; writes typed by the node, range-checked, never wrapped."""

from __future__ import annotations

import math

import pytest
from asyncua import ua

from compd.drivers.opcua.values import INT_RANGES, to_float, to_variant, variant_type
from compd.errors import DriverProtocolError


@pytest.mark.parametrize("vtype", list(INT_RANGES), ids=lambda t: t.name)
def test_integer_writes_fit_their_type_or_are_refused(vtype):
    """Every integer type takes its limits (after rounding) and refuses one past each, never wrapping."""
    low, high = INT_RANGES[vtype]
    assert to_variant("p", float(low), vtype).Value == low
    if high < 2**53:  # float64 holds the 64-bit maxima only approximately (2**63 - 1 -> 2**63)
        assert to_variant("p", high - 0.4, vtype).Value == high
    step = 1.0 if high < 2**53 else 4096.0  # the float64 spacing near 2**63 is 2048
    for outside in (low - step, high + 0.6 * step):
        with pytest.raises(DriverProtocolError, match=vtype.name):
            to_variant("p", outside, vtype)


def test_float_and_boolean_writes():
    """Float refuses values beyond float32, non-finite values are refused for all types, Boolean takes 0/1."""
    assert to_variant("p", 1e38, ua.VariantType.Float).VariantType == ua.VariantType.Float
    with pytest.raises(DriverProtocolError, match="does not fit Float"):
        to_variant("p", 1e39, ua.VariantType.Float)
    for vtype in (ua.VariantType.Double, ua.VariantType.Int32, ua.VariantType.Boolean):
        with pytest.raises(DriverProtocolError, match="not finite"):
            to_variant("p", float("inf"), vtype)
    assert to_variant("p", 0.0, ua.VariantType.Boolean).Value is False
    with pytest.raises(DriverProtocolError, match="not 0 or 1"):
        to_variant("p", 2.0, ua.VariantType.Boolean)


def test_read_values_and_data_types():
    """Numbers and Booleans read as floats, other values are protocol errors; builtin DataTypes map to variants."""
    assert [to_float("p", v) for v in (True, -3, 2.5)] == [1.0, -3.0, 2.5]
    with pytest.raises(DriverProtocolError, match="not a number"):
        to_float("p", "21.5")
    assert variant_type(ua.NodeId(4, 0)) == ua.VariantType.Int16
    assert variant_type(ua.NodeId(3002, 0)) is None  # not builtin: a structure or enum
    assert variant_type(ua.NodeId("MyType", 2)) is None


def test_non_finite_and_absurd_numbers_read_as_they_are():
    """NaN, inf, 3e38 and 2**64 read through unchanged: the service judges an offset read back, not the driver."""
    values = [to_float("p", v) for v in (float("nan"), float("-inf"), 3e38, 2**64)]
    assert math.isnan(values[0]) and values[1:] == [float("-inf"), 3e38, 2.0**64]
