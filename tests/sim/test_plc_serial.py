"""The simulated PLC's serial scanner against compd's own serial-sensor driver, on a pty in one event loop."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

import pytest

from compd.drivers.serial_lines import SerialSensorSettings, checksum_hex
from compd.drivers.serial_sensor import SerialSensorDriver
from compd.errors import DriverProtocolError
from compd.service.loop.clock import VirtualClock
from compd.service.loop.links import DriverLink
from compd.sim.plc.serial import SerialPlcServer
from tests.reconnect import seconds_until_read

VALUES = {"1": 23.456, "2": -5.25, "3": 1e-7, "4": 351.0}


def settings(port: Path, **options: Any) -> SerialSensorSettings:
    options.setdefault("reply_timeout_s", 0.2)
    return SerialSensorSettings(port=str(port), **options)


def scanner(s: SerialSensorSettings, inputs: list[str] | None = None, **kw: Any) -> SerialPlcServer:
    return SerialPlcServer(
        s,
        inputs=list(VALUES) if inputs is None else inputs,
        outputs=[],
        on_write=lambda a, v: None,
        base_dir=Path(),
        **kw,
    )


def driver(s: SerialSensorSettings) -> SerialSensorDriver:
    return SerialSensorDriver(s, now=time.monotonic, base_dir=Path())


def serve(
    s: SerialSensorSettings,
    scenario: Callable[[SerialPlcServer, SerialSensorDriver], Awaitable[None]],
) -> None:
    """Run ``scenario`` with a started scanner (VALUES published) and an open driver."""

    async def main() -> None:
        server = scanner(s)
        await server.start()
        server.publish(VALUES)
        client = driver(s)
        try:
            await client.open()
            await scenario(server, client)
        finally:
            await client.close()
            await server.stop()

    asyncio.run(main())


@pytest.mark.parametrize(
    "options",
    [
        {},
        {"checksum": "xor"},
        {"checksum": "sum8", "request_checksum": True, "checksum_skip": "$"},
        {"request": "READ", "item_separator": ";"},
        {"request": "T? {channel}", "reply": r"(?P<value>[-+]?\d+\.?\d*(?:e[-+]?\d+)?)"},
        {
            "request": "SCAN {{{channels}}}",
            "channel_separator": " ",
            "reply": r"CH(?P<channel>\d+)\s+(?P<value>\S+)",
            "item_separator": "|",
        },
        {"poll": "background", "channels": ("1", "2", "3", "4"), "poll_period_s": 0.02},
    ],
    ids=[
        "default",
        "xor",
        "sum8 both ways",
        "fixed request",
        "per channel",
        "custom",
        "background",
    ],
)
def test_published_values_read_back_exactly_in_the_drivers_protocol(
    tmp_path: Path, options: dict[str, Any]
):
    """Whatever template, reply pattern, separators and checksums the driver uses, it reads the published values."""
    s = settings(tmp_path / "ttyScan", **options)

    async def scenario(server: SerialPlcServer, client: SerialSensorDriver) -> None:
        if s.poll == "background":
            await asyncio.sleep(0.05)
        assert await client.read(list(VALUES)) == VALUES
        server.publish({"2": 30.5})
        if s.poll == "background":
            await asyncio.sleep(0.05)
        assert await client.read(["2", "4"]) == {"2": 30.5, "4": 351.0}

    serve(s, scenario)


@pytest.mark.parametrize(
    ("reply", "item_format", "line"),
    [
        (r"CH(?P<channel>\d+)\s+(?P<value>\S+)", None, "CH1 23.456,CH2 -5.25"),
        (r"T(?P<channel>\d)\{(?P<value>\S+)\}", None, "T1{23.456},T2{-5.25}"),
        (r"(?P<channel>\d)(?P<value>\S+)", None, "123.456,2-5.25"),
        (r"(?P<channel>\d)[:=](?P<value>\S+)", None, "1=23.456,2=-5.25"),
        (r"(?P<channel>\d)[:=](?P<value>\S+)", "{channel}:{value}", "1:23.456,2:-5.25"),
    ],
)
def test_the_reply_shape_follows_the_pattern(
    tmp_path: Path, reply: str, item_format: str | None, line: str
):
    """Items take the given shape, else the reply pattern's own (groups filled in), else a common one."""
    s = settings(tmp_path / "tty", reply=reply, request="SCAN {channels}")
    server = scanner(s, ["1", "2"], item_format=item_format)
    server.publish({"1": 23.456, "2": -5.25})
    assert server.answer("SCAN 1,2") == line


def test_a_checksummed_reply_is_the_drivers_checksum_after_the_delimiter(tmp_path: Path):
    """With checksum: xor the reply is payload*HH, HH the XOR of the payload's bytes."""
    server = scanner(settings(tmp_path / "tty", checksum="xor"), ["1", "2"])
    server.publish({"1": 23.456, "2": -5.25})
    payload = "1=23.456,2=-5.25"
    assert server.answer("MEAS? 1,2") == f"{payload}*{checksum_hex(payload.encode(), 'xor')}"


def test_requests_the_scanner_cannot_answer_get_an_err_line(tmp_path: Path):
    """An unknown command or channel, a channel never published or a bad checksum gets ERR; the driver refuses it."""
    server = scanner(settings(tmp_path / "tty", checksum="xor", request_checksum=True), ["1", "2"])
    server.publish({"1": 23.456})
    request = "MEAS? 1"
    good = f"{request}*{checksum_hex(request.encode(), 'xor')}"
    assert server.answer(good) == "1=23.456*" + checksum_hex(b"1=23.456", "xor")
    assert server.answer("MEAS? 1*00") == "ERR checksum"
    assert server.answer("MEAS? 1") == "ERR checksum"
    assert server.answer(f"HELLO*{checksum_hex(b'HELLO', 'xor')}") == "ERR unknown command"
    assert server.answer(f"MEAS? 9*{checksum_hex(b'MEAS? 9', 'xor')}") == "ERR unknown channel 9"
    assert (
        server.answer(f"MEAS? 2*{checksum_hex(b'MEAS? 2', 'xor')}") == "ERR no reading on channel 2"
    )

    async def scenario(server: SerialPlcServer, client: SerialSensorDriver) -> None:
        with pytest.raises(DriverProtocolError, match="ERR unknown channel 9"):
            await client.read(["1", "9"])
        assert await client.read(["1"]) == {"1": 23.456}

    serve(settings(tmp_path / "tty2"), scenario)


def test_unplug_and_replug_through_the_link(tmp_path: Path):
    """stop() hangs the port up and removes the link; after start() at the same path the DriverLink resumes in < 5 s."""
    port = tmp_path / "serial" / "by-id" / "usb-scanner"  # the parent folders are made
    s = settings(port)

    async def main() -> tuple[float, DriverLink]:
        server = scanner(s)
        await server.start()
        server.publish(VALUES)
        clock = VirtualClock()  # the backoff's clock: the retries counted, not the machine's speed
        # timeout_s only ends a hung read: a short one times out good reads on a busy host.
        link = DriverLink("scanner", driver(s), clock, timeout_s=10.0, backoff_min_s=0.05)
        await link.open()
        assert await link.read(["1"]) == {"1": 23.456}
        await server.stop()
        assert not port.is_symlink()
        await asyncio.sleep(0.05)  # the hang-up reaches the event loop
        assert await link.read(["1"]) == {}
        await asyncio.sleep(0.1)  # reconnects fail while unplugged
        assert await link.read(["1"]) == {}
        server.publish({"1": 24.0})
        await server.start()
        resumed_s = await seconds_until_read(link, clock, ["1"])
        assert await link.read(["1"]) == {"1": 24.0}
        await link.close()
        await server.stop()
        return resumed_s, link

    resumed_s, link = asyncio.run(main())
    assert resumed_s < 5.0 and link.reconnects == 1
    assert not port.exists()


def test_a_path_that_is_not_a_symlink_is_never_replaced(tmp_path: Path):
    """start() refuses to put the pty where a real file (or device) is, and leaves it as it was."""
    port = tmp_path / "ttyUSB0"
    port.write_text("not a port")

    async def main() -> None:
        with pytest.raises(RuntimeError, match=r"not a symlink.*refusing to replace"):
            await scanner(settings(port)).start()

    asyncio.run(main())
    assert port.read_text() == "not a port"


def test_a_stale_symlink_is_replaced(tmp_path: Path):
    """A symlink left from an earlier run (dangling) is replaced by the new pty's."""
    port = tmp_path / "ttyUSB0"
    port.symlink_to(tmp_path / "gone")
    s = settings(port)

    async def scenario(server: SerialPlcServer, client: SerialSensorDriver) -> None:
        assert await client.read(["3"]) == {"3": 1e-7}

    serve(s, scenario)


def test_configurations_the_scanner_cannot_serve_are_refused_with_the_fix(tmp_path: Path):
    """Outputs, undeclared channels, an unservable reply pattern, unknown channels published: errors with the fix."""
    s = settings(tmp_path / "tty")
    with pytest.raises(ValueError, match=r"takes no writes.*controller's driver"):
        SerialPlcServer(s, inputs=["1"], outputs=["1"], on_write=lambda a, v: None, base_dir=Path())
    with pytest.raises(ValueError, match=r"\['9'\] are not among the scanner's 'channels'"):
        scanner(settings(tmp_path / "tty", channels=("1", "2")), ["1", "9"])
    with pytest.raises(ValueError, match=r"channels \['7'\] are not inputs of the scanner"):
        scanner(s, ["1"]).publish({"1": 20.0, "7": 21.0})
    with pytest.raises(ValueError, match="pass item_format="):
        # Three decimals, no sign: repr() of a raw value does not fit it.
        scanner(settings(tmp_path / "tty", reply=r"(?P<channel>\d+)=(?P<value>\d+\.\d{3})"))
