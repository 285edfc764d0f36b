"""The ASCII line protocol: settings validation, checksums, request framing, reply parsing, the example config."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from pydantic import ValidationError

from compd.drivers.serial_lines import (
    SerialSensorSettings,
    checksum_hex,
    frame_request,
    parse_values,
    reply_payload,
)
from compd.errors import ConfigFileError, DriverProtocolError
from compd.service.config.loading import parse_config

EXAMPLE_CONFIG = Path(__file__).parents[2] / "config" / "compd.example.yaml"


def test_checksums_match_published_and_independent_values():
    """XOR reproduces a published NMEA checksum; sum8 is the byte sum modulo 256."""
    sentence = b"GPRMC,092750.000,A,5321.6802,N,00630.3372,W,0.02,31.66,280511,,,A"
    assert checksum_hex(sentence, "xor") == "43"
    data = b"1=+23.456,2=+24.101"
    assert checksum_hex(data, "sum8") == f"{sum(data) % 256:02X}"


@pytest.mark.parametrize(
    ("settings", "message"),
    [
        ({"request": "MEAS? {chan}"}, "may name"),
        ({"reply": r"(?P<value>\d+"}, "not a valid regular expression"),
        ({"reply": r"\d+"}, "(?P<value>"),
        ({"reply": r"(?P<value>\d+)"}, "needs a (?P<channel>"),
        ({"range": (10, 5)}, "min < max"),
        ({"channels": ("1",), "channel_ranges": {"2": (0, 1)}}, "not in 'channels'"),
        ({"baudrate": 0}, "greater than 0"),
        ({"stopbits": 3}, "stop bits must be 1, 1.5 or 2"),
        ({"poll": "background"}, "needs 'channels'"),
    ],
)
def test_bad_settings_are_refused(settings, message):
    """Settings that cannot work (bad template, pattern, range or port options) fail validation with a reason."""
    with pytest.raises(ValidationError, match=re.escape(message)):
        SerialSensorSettings(port="/dev/ttyUSB0", **settings)


def uncommented_example() -> str:
    """config/compd.example.yaml with its serial-scanner driver and signal blocks uncommented."""
    lines = EXAMPLE_CONFIG.read_text().splitlines()
    for header in ("  # scanner:", "  # T_column_degC:"):
        start = next(i for i, line in enumerate(lines) if line.startswith(header))
        lines[start] = lines[start].replace("# ", "", 1)
        end = start + 1
        while lines[end].startswith("  #   "):
            lines[end] = lines[end].replace("#   ", "  ", 1)
            end += 1
    return "\n".join(lines) + "\n"


def test_example_config_validates_with_the_scanner():
    """The commented serial example in config/compd.example.yaml is a valid config once uncommented."""
    config = parse_config(uncommented_example(), EXAMPLE_CONFIG)
    settings = config.driver_settings["scanner"]
    assert isinstance(settings, SerialSensorSettings) and settings.checksum == "xor"
    assert settings.poll == "background" and settings.channels == ("1", "2", "3", "4")
    assert config.doc.signals["T_column_degC"].driver == "scanner"


def test_config_error_names_the_driver_instance_and_key():
    """A bad serial setting in a config file is an error naming the driver instance, the key and its line."""
    text = uncommented_example().replace("checksum: xor ", "checksum: crc16 ")
    with pytest.raises(ConfigFileError, match=r"line \d+ \(drivers\.scanner\.settings\.checksum\)"):
        parse_config(text, EXAMPLE_CONFIG)


def test_nmea_style_reply_with_a_skipped_prefix():
    """With checksum_skip '$' the checksum covers the text between '$' and '*'; the payload is returned without them."""
    settings = SerialSensorSettings(
        port="/dev/ttyUSB0",
        checksum="xor",
        checksum_skip="$",
        reply=r"(?P<value>[-+]?\d+\.\d+)",
        request="T? {channel}",
        item_separator="",
    )
    sentence = "GPRMC,092750.000,A,5321.6802,N,00630.3372,W,0.02,31.66,280511,,,A"
    assert reply_payload(settings, f"${sentence}*43\r\n".encode()) == sentence
    with pytest.raises(DriverProtocolError, match="bad xor checksum"):
        reply_payload(settings, f"${sentence}*44\r\n".encode())


def test_sum8_request_framing_and_a_reply_without_channel_names():
    """A sum8 request ends in its byte sum modulo 256 and the terminator; a one-channel reply needs no channel group."""
    settings = SerialSensorSettings(
        port="/dev/ttyUSB0",
        request="T? {channel}",
        request_terminator="\r",
        checksum="sum8",
        request_checksum=True,
        reply=r"T=(?P<value>[-+]?\d+\.\d+)",
        item_separator="",
    )
    text, frame = frame_request(settings, channel="7")
    assert text == f"T? 7*{sum(b'T? 7') % 256:02X}" and frame == (text + "\r").encode()
    pattern = re.compile(settings.reply)
    assert parse_values(settings, pattern, "T=+21.50", ["7"]) == {"7": 21.5}
    with pytest.raises(DriverProtocolError, match="does not match the reply pattern"):
        parse_values(settings, pattern, "T=OVER", ["7"])


def test_a_reply_missing_a_requested_channel_yields_nothing():
    """A batch reply lacking one of the requested channels raises instead of returning the others."""
    settings = SerialSensorSettings(port="/dev/ttyUSB0")
    pattern = re.compile(settings.reply)
    with pytest.raises(DriverProtocolError, match=re.escape("no value for channel(s) ['3']")):
        parse_values(settings, pattern, "1=+20.000,2=+21.000", ["1", "2", "3"])
