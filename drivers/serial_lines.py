"""The line protocol of ASCII sensor scanners: settings, request framing, checksums, reply parsing.

Pure functions on text and bytes (no I/O), used by
:mod:`compd.drivers.serial_sensor`. A request is the ``request`` template
with its ``{channels}`` (all, joined by ``channel_separator``) or
``{channel}`` (one) filled in, an optional checksum and the terminator. A
reply line is decoded as ASCII, its checksum (if any) checked and removed,
split into items on ``item_separator``, and every item must *fully* match
the ``reply`` pattern, whose named groups give ``value`` and ``channel``. Any
deviation raises :class:`~compd.errors.DriverProtocolError` and the whole
reply is discarded: a poll yields all its values or none.

Checksums, NMEA style, two hex digits after ``checksum_delimiter`` covering
the text before it (less a ``checksum_skip`` prefix such as ``$``)::

    xor:   c = b_1 ^ b_2 ^ ... ^ b_n
    sum8:  c = (b_1 + b_2 + ... + b_n) mod 256
"""

from __future__ import annotations

import re
import string
from collections.abc import Sequence
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from compd.errors import DriverProtocolError

DEFAULT_REPLY = r"(?P<channel>\w+)=(?P<value>[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)"

Range = tuple[
    Annotated[float, Field(allow_inf_nan=False)], Annotated[float, Field(allow_inf_nan=False)]
]


class SerialSensorSettings(BaseModel):
    """``drivers.<name>.settings`` of a ``type: serial_sensor`` driver."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    port: str = Field(min_length=1, description="serial device, e.g. /dev/serial/by-id/usb-...")
    baudrate: int = Field(default=9600, gt=0)
    bytesize: Literal[5, 6, 7, 8] = 8
    parity: Literal["N", "E", "O", "M", "S"] = "N"
    stopbits: float = 1
    request: str = Field(default="MEAS? {channels}", description="{channels} or {channel}")
    channel_separator: str = Field(default=",", description="joins channels in {channels}")
    request_terminator: str = "\r\n"
    reply_terminator: str = Field(default="\r\n", min_length=1)
    reply: str = Field(default=DEFAULT_REPLY, description="regex: groups 'value', 'channel'")
    item_separator: str = Field(default=",", description="splits a reply into items; '' none")
    checksum: Literal["none", "xor", "sum8"] = "none"
    checksum_delimiter: str = Field(default="*", min_length=1)
    checksum_skip: str = Field(default="", description="leading characters not summed, e.g. $")
    request_checksum: bool = False
    reply_timeout_s: float = Field(default=0.2, gt=0, allow_inf_nan=False)
    #: Missed replies in a row that leave the values stale before the port counts as lost.
    max_missed_replies: int = Field(default=3, ge=1)
    channels: tuple[str, ...] = Field(default=(), description="the channels the device has")
    range: Range | None = Field(default=None, description="[min, max] of every sensor")
    channel_ranges: dict[str, Range] = Field(default_factory=dict)
    poll: Literal["on_read", "background"] = Field(
        default="on_read", description="background: poll every poll_period_s, reads never wait"
    )
    poll_period_s: float = Field(default=1.0, gt=0, allow_inf_nan=False)

    @field_validator("stopbits")
    @classmethod
    def _stopbits(cls, stopbits: float) -> float:
        if stopbits not in (1, 1.5, 2):
            raise ValueError(f"stop bits must be 1, 1.5 or 2, not {stopbits}")
        return stopbits

    @field_validator("request")
    @classmethod
    def _one_placeholder(cls, request: str) -> str:
        fields = {name for _, name, _, _ in string.Formatter().parse(request) if name is not None}
        if not fields <= {"channel", "channels"} or len(fields) > 1:
            raise ValueError(
                f"the request may name '{{channels}}' (all in one request) or '{{channel}}' "
                f"(one request each), not {sorted(fields)}; write a literal brace as '{{{{'"
            )
        return request

    @field_validator("reply")
    @classmethod
    def _compiles(cls, reply: str) -> str:
        try:
            pattern = re.compile(reply)
        except re.error as exc:
            raise ValueError(f"not a valid regular expression: {exc}") from None
        if "value" not in pattern.groupindex:
            raise ValueError("the reply pattern needs a named group (?P<value>...)")
        return reply

    @model_validator(mode="after")
    def _consistent(self) -> SerialSensorSettings:
        if not self.per_channel and "channel" not in re.compile(self.reply).groupindex:
            raise ValueError(
                "a request for all channels at once needs a (?P<channel>...) group in 'reply' "
                "to tell the values apart; or request one channel at a time with '{channel}'"
            )
        for low, high in [*([self.range] if self.range else []), *self.channel_ranges.values()]:
            if low >= high:
                raise ValueError(f"a range [{low}, {high}] must be [min, max] with min < max")
        if self.poll == "background" and not self.channels:
            raise ValueError("poll: background needs 'channels': the poller asks for all of them")
        undeclared = sorted(set(self.channel_ranges) - set(self.channels)) if self.channels else []
        if undeclared:
            raise ValueError(f"'channel_ranges' names channels not in 'channels': {undeclared}")
        return self

    @property
    def per_channel(self) -> bool:
        """One request per channel (the template names ``{channel}``)."""
        return "{channel}" in self.request


def checksum_hex(data: bytes, kind: Literal["xor", "sum8"]) -> str:
    """Two upper-case hex digits: the XOR of ``data``'s bytes, or their sum modulo 256."""
    total = 0
    for byte in data:
        total = total ^ byte if kind == "xor" else (total + byte) & 0xFF
    return f"{total:02X}"


def frame_request(settings: SerialSensorSettings, **fields: str) -> tuple[str, bytes]:
    """The request text (for messages) and the bytes to send: template, checksum, terminator."""
    s = settings
    request = s.request.format(**fields)
    if s.request_checksum and s.checksum != "none":
        covered = request.removeprefix(s.checksum_skip).encode("latin-1")
        request += s.checksum_delimiter + checksum_hex(covered, s.checksum)
    return request, (request + s.request_terminator).encode("latin-1")


def reply_payload(settings: SerialSensorSettings, line: bytes) -> str:
    """The reply line as text without terminator whitespace and checksum, the checksum verified."""
    s = settings
    try:
        text = line.decode("ascii").strip()
    except UnicodeDecodeError:
        raise DriverProtocolError(f"reply from {s.port} is not ASCII: {line[:80]!r}") from None
    if s.checksum == "none":
        return text
    payload, delimiter, given = text.rpartition(s.checksum_delimiter)
    if not delimiter:
        raise DriverProtocolError(f"reply from {s.port} has no checksum: {text[:80]!r}")
    payload = payload.removeprefix(s.checksum_skip)
    expected = checksum_hex(payload.encode("ascii"), s.checksum)
    if given.upper() != expected:
        raise DriverProtocolError(
            f"bad {s.checksum} checksum from {s.port}: got {given!r}, computed {expected} "
            f"for {text[:80]!r}"
        )
    return payload


def parse_values(
    settings: SerialSensorSettings, pattern: re.Pattern[str], payload: str, channels: Sequence[str]
) -> dict[str, float]:
    """``{channel: value}`` for every one of ``channels`` from one reply payload, or raise."""
    fields = parse_fields(settings, pattern, payload, channels)
    return {channel: field_value(settings, channel, text) for channel, text in fields.items()}


def field_value(settings: SerialSensorSettings, channel: str, text: str | None) -> float:
    """A reply's value field as a number, or DriverProtocolError naming the channel."""
    try:
        return float(text)  # type: ignore[arg-type]  # None: the TypeError below
    except (TypeError, ValueError):
        raise DriverProtocolError(
            f"channel {channel} value {text!r} from {settings.port} is not a number"
        ) from None


def parse_fields(
    settings: SerialSensorSettings, pattern: re.Pattern[str], payload: str, channels: Sequence[str]
) -> dict[str, str]:
    """``{channel: value field as sent}`` for every one of ``channels`` from one reply payload, or raise."""
    s = settings
    items = payload.split(s.item_separator) if s.item_separator else [payload]
    found: dict[str, str] = {}
    for item in items:
        match = pattern.fullmatch(item.strip())
        if match is None:
            raise DriverProtocolError(
                f"reply from {s.port} does not match the reply pattern: {payload[:80]!r}"
            )
        groups = match.groupdict()
        channel = groups.get("channel") or (channels[0] if len(channels) == 1 else None)
        if channel is None:
            raise DriverProtocolError(f"reply from {s.port} names no channel: {payload[:80]!r}")
        found[channel] = groups["value"]
    missing = [c for c in channels if c not in found]
    if missing:
        raise DriverProtocolError(
            f"reply from {s.port} has no value for channel(s) {missing}: {payload[:80]!r}"
        )
    return {c: found[c] for c in channels}
