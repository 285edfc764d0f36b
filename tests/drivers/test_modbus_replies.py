"""The Modbus driver against a real pymodbus server whose replies are rewritten on the wire.

The server's ``trace_packet`` hook replaces each read reply's PDU (the MBAP
header kept consistent, so the frame itself is well formed) with one of the
wrong shape: too few or too many registers, a byte count that lies, another
function code, an exception code no device uses. A reply that is not an
answer to the request must be a DriverError, never values.
"""

from __future__ import annotations

import asyncio
import struct
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from pymodbus.server import ModbusTcpServer

from compd.drivers.modbus.driver import ModbusDriver
from compd.drivers.modbus.settings import ModbusSettings
from compd.errors import DriverError

from .modbus_server import INPUTS, ServerThread, free_port, make_device

READ_INPUT = 0x04
ASKED = 10  # INPUTS spans input registers 0..9: one request per read


class Rewriter:
    """The server's ``trace_packet`` hook: a sent read reply's PDU becomes ``pdu`` while set."""

    def __init__(self) -> None:
        self.pdu: bytes | None = None

    def __call__(self, sending: bool, packet: bytes) -> bytes:
        if not sending or self.pdu is None or packet[7:8] != bytes([READ_INPUT]):
            return packet
        # MBAP: transaction id, protocol id, length (unit id + PDU), unit id.
        return packet[:4] + struct.pack(">H", len(self.pdu) + 1) + packet[6:7] + self.pdu


@pytest.fixture(scope="module")
def rewriting() -> Iterator[tuple[int, Rewriter]]:
    """A pymodbus TCP server whose read replies the test rewrites; yields its port and the hook."""
    port, hook = free_port(), Rewriter()
    thread = ServerThread(
        lambda: ModbusTcpServer(make_device(), address=("127.0.0.1", port), trace_packet=hook)
    )
    thread.start()
    yield port, hook
    thread.stop()


def _registers(draw: st.DrawFn) -> bytes:
    """Function 4 with a register payload of the wrong length (its byte count true or not)."""
    count = draw(st.integers(0, 125).filter(lambda n: n != ASKED))
    data = draw(st.binary(min_size=2 * count, max_size=2 * count))
    byte_count = draw(st.just(2 * count) | st.integers(0, 255))
    return bytes([READ_INPUT, byte_count]) + data


@st.composite
def wrong_pdus(draw: st.DrawFn) -> bytes:
    """A PDU that answers no read of 10 input registers."""
    kind = draw(st.sampled_from(["registers", "odd", "function", "exception", "truncated"]))
    if kind == "registers":
        return _registers(draw)
    if kind == "odd":  # a byte count of half a register
        count = draw(st.integers(0, 127)) * 2 + 1
        return bytes([READ_INPUT, count]) + draw(st.binary(min_size=count, max_size=count))
    if kind == "function":
        function = draw(st.integers(1, 127).filter(lambda f: f != READ_INPUT))
        return bytes([function]) + draw(st.binary(max_size=40))
    if kind == "exception":
        return bytes([READ_INPUT | 0x80, draw(st.integers(0, 255))])
    return draw(st.binary(max_size=1))


def test_wrong_register_payloads_raise_only_driver_errors(rewriting):
    """A read answered by a reply of the wrong shape raises DriverError; the next true reply reads again."""
    port, hook = rewriting
    driver = ModbusDriver(
        ModbusSettings(host="127.0.0.1", port=port, request_timeout_s=0.2),
        now=time.monotonic,
        base_dir=Path(),
    )

    async def read(pdu: bytes | None) -> dict[str, float]:
        hook.pdu = pdu
        await driver.open()
        try:
            return await driver.read(list(INPUTS))
        finally:
            await driver.close()

    with asyncio.Runner() as runner:

        @settings(max_examples=25, deadline=None)
        @given(pdu=wrong_pdus())
        # 21 bytes after a byte count of 21: pymodbus read them as 10 registers and dropped one.
        @example(pdu=bytes([READ_INPUT, 21]) + bytes(21))
        def check(pdu: bytes) -> None:
            with pytest.raises(DriverError):
                runner.run(read(pdu))

        check()
        assert runner.run(read(None)) == INPUTS
