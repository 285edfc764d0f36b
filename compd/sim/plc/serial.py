"""The simulated PLC's serial scanner: a multi-channel temperature scanner on a pseudo-terminal.

One :class:`SerialPlcServer` stands where one ``type: serial_sensor`` driver
instance connects: ``settings.port`` becomes a symlink to the slave side of
a pty pair (as a udev rule names a USB adapter ``/dev/serial/by-id/...``),
and the scanner answers on the master side, in the caller's event loop
(``loop.add_reader``, no thread).

It speaks the driver's own protocol, from the same settings and the same
pieces (:mod:`compd.drivers.serial_lines`): requests framed by the
``request`` template (``{channels}`` joined by ``channel_separator``, or one
``{channel}``), with a checked checksum when ``request_checksum`` is set;
replies are items joined by ``item_separator``, each rendered so that it
fully matches the ``reply`` pattern, then ``checksum_skip``, the checksum
after ``checksum_delimiter``, and ``reply_terminator``. The item shape is
found at construction (or given as ``item_format``): the pattern itself with
its groups filled in (``CH(?P<channel>\\d+)\\s+(?P<value>\\S+)`` gives
``CH{channel} {value}``), else the first of :data:`ITEM_FORMATS`, as long as
the driver's parser reads sample items back exactly.

A request the scanner cannot answer (unknown command, unknown or never
published channel, bad checksum) is answered with an ``ERR ...`` line, as
real scanners do; the driver sees a reply that does not match its pattern.
Values are written with ``repr`` (shortest exact form), so a published raw
value reads back exactly; a non-finite value is written ``nan``/``inf``,
which the default pattern does not accept (the driver reports a bad reply).

``stop`` closes the pty (the driver's port hangs up) and removes the
symlink; ``start`` makes a new pty behind the same symlink (a replug).
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import re
import string
import tty
from collections.abc import Mapping, Sequence
from pathlib import Path

from compd.drivers.serial_lines import SerialSensorSettings, checksum_hex, parse_values
from compd.errors import DriverProtocolError
from compd.sim.plc.server import PlcServerType, WriteSink

__all__ = ["ITEM_FORMATS", "SerialPlcServer"]

#: Reply item shapes tried in order against the settings' ``reply`` pattern.
ITEM_FORMATS: tuple[str, ...] = (
    "{channel}={value}",
    "{channel}:{value}",
    "{channel} {value}",
    "{channel},{value}",
    "{channel};{value}",
    "{value}",
)
#: A request line longer than this without a terminator is dropped, not answered.
MAX_REQUEST_BYTES = 4096
_SAMPLE_VALUES = (23.456, -5.25, 3000.0)


class SerialPlcServer:
    """A scanner on a pty behind the symlink ``settings.port``; see the module docstring."""

    def __init__(
        self,
        settings: SerialSensorSettings,
        *,
        inputs: Sequence[str],
        outputs: Sequence[str],
        on_write: WriteSink,
        base_dir: Path,
        item_format: str | None = None,
    ) -> None:
        if outputs:
            raise ValueError(
                f"a serial scanner takes no writes, but outputs {list(outputs)} are configured on "
                f"its driver ({settings.port}); put outputs on the controller's driver"
            )
        declared = set(settings.channels)
        unknown = [c for c in inputs if declared and c not in declared]
        if unknown:
            raise ValueError(
                f"channels {unknown} are not among the scanner's 'channels' {list(settings.channels)}"
            )
        if not settings.item_separator and not settings.per_channel and len(inputs) > 1:
            raise ValueError(
                f"{settings.port}: with item_separator '' a reply holds one value: request one "
                "channel at a time ('{channel}' in 'request') or set an item_separator"
            )
        self.settings = settings
        self.link = Path(settings.port)
        self.inputs = tuple(dict.fromkeys(inputs))
        self._inputs = frozenset(self.inputs)
        self._pattern = re.compile(settings.reply)
        self._item_format = item_format or _find_item_format(
            settings, self._pattern, self.inputs[:2] or ("1",)
        )
        self._request = _request_pattern(settings)
        self._request_terminator = settings.request_terminator.encode("latin-1")
        self._values: dict[str, float] = {}
        self._master = self._slave = -1
        self._received = b""
        #: Request lines answered (with values or with ``ERR``), for tests.
        self.requests = 0

    @property
    def started(self) -> bool:
        return self._master >= 0

    async def start(self) -> None:
        """Open a new pty and point the symlink at its slave; answer from now on."""
        if self.started:
            return
        if os.path.lexists(self.link) and not self.link.is_symlink():
            raise RuntimeError(
                f"simulated scanner: {self.link} exists and is not a symlink (a real port or a "
                "file?); refusing to replace it: point the driver's 'port' at a free path"
            )
        self.link.parent.mkdir(parents=True, exist_ok=True)
        master, slave = os.openpty()
        try:
            # Raw from the start: no echo of requests back to the driver before it configures the port.
            tty.setraw(slave)
            os.set_blocking(master, False)
            tmp = self.link.with_name(self.link.name + ".new")
            tmp.unlink(missing_ok=True)
            tmp.symlink_to(os.ttyname(slave))
            tmp.replace(self.link)  # atomic: the driver never sees the link missing
            asyncio.get_running_loop().add_reader(master, self._readable)
        except BaseException:
            os.close(master)
            os.close(slave)
            raise
        # The slave stays open here too: without it, the master reads EIO whenever
        # the driver closes its port, and the pty would vanish between reconnects.
        self._master, self._slave, self._received = master, slave, b""

    async def stop(self) -> None:
        """Close the pty (the driver's port hangs up) and remove the symlink; never raises."""
        master, slave = self._master, self._slave
        if master < 0:
            return
        self._master = self._slave = -1
        with contextlib.suppress(Exception):
            asyncio.get_running_loop().remove_reader(master)
        for fd in (master, slave):
            with contextlib.suppress(OSError):
                os.close(fd)
        with contextlib.suppress(OSError):
            if self.link.is_symlink():
                self.link.unlink()

    def publish(self, values: Mapping[str, float]) -> None:
        """Answer with these raw values from now on (channel -> value); ValueError names an unknown channel."""
        if not self._inputs.issuperset(values):
            unknown = sorted(set(values) - self._inputs)
            raise ValueError(
                f"channels {unknown} are not inputs of the scanner on {self.link}; "
                f"it serves {list(self.inputs)}"
            )
        self._values.update(values)

    # -- the scanner ------------------------------------------------------

    def answer(self, request: str) -> str:
        """The reply line (without terminator) to one request line."""
        s = self.settings
        if s.request_checksum and s.checksum != "none":
            request, delimiter, given = request.rpartition(s.checksum_delimiter)
            covered = request.removeprefix(s.checksum_skip).encode("latin-1")
            if not delimiter or given.upper() != checksum_hex(covered, s.checksum):
                return "ERR checksum"
        match = self._request.fullmatch(request)
        if match is None:
            return "ERR unknown command"
        fields = match.groupdict()
        if "channel" in fields:
            channels = [fields["channel"]]
        elif "channels" in fields:
            text = fields["channels"]
            channels = text.split(s.channel_separator) if s.channel_separator else [text]
        else:
            channels = list(self.inputs)
        items = []
        for channel in channels:
            if channel not in self.inputs:
                return f"ERR unknown channel {channel}"
            if channel not in self._values:
                return f"ERR no reading on channel {channel}"
            items.append(
                self._item_format.format(channel=channel, value=repr(self._values[channel]))
            )
        payload: str = s.item_separator.join(items)
        if s.checksum == "none":
            return payload
        digits: str = checksum_hex(payload.encode("latin-1"), s.checksum)
        return f"{s.checksum_skip}{payload}{s.checksum_delimiter}{digits}"

    def _readable(self) -> None:
        try:
            data = os.read(self._master, 4096)
        except OSError:  # BlockingIOError (spurious wake-up), or the pty is going away
            return
        *lines, self._received = (self._received + data).split(self._request_terminator)
        if len(self._received) > MAX_REQUEST_BYTES:
            self._received = b""
        for line in lines:
            if not line.strip():
                continue
            self.requests += 1
            reply = self.answer(line.decode("latin-1")) + self.settings.reply_terminator
            with contextlib.suppress(OSError):  # a full pty buffer: the reply is lost, as on a wire
                os.write(self._master, reply.encode("latin-1"))


_: PlcServerType = SerialPlcServer  # mypy checks the class against the server contract


def _request_pattern(settings: SerialSensorSettings) -> re.Pattern[str]:
    """The request template as a regex: literal text, ``{channels}``/``{channel}`` as named groups."""
    pattern = ""
    for literal, name, _, _ in string.Formatter().parse(settings.request):
        pattern += re.escape(literal)
        if name is not None:  # 'channel' or 'channels': checked by SerialSensorSettings
            pattern += f"(?P<{name}>.+?)"
    return re.compile(pattern)


def _find_item_format(
    settings: SerialSensorSettings, pattern: re.Pattern[str], channels: Sequence[str]
) -> str:
    """The pattern's own shape, or else the first of :data:`ITEM_FORMATS`, whose sample items parse back exactly."""
    guess = _shape_of(settings.reply)
    for item_format in ([guess] if guess else []) + list(ITEM_FORMATS):
        if "channel" in pattern.groupindex and "{channel}" not in item_format:
            continue
        if all(
            _parses_back(settings, pattern, item_format, c, v)
            for c in channels
            for v in _SAMPLE_VALUES
        ):
            return item_format
    raise ValueError(
        f"the simulated scanner cannot write replies matching the reply pattern {settings.reply!r} "
        f"of {settings.port}: none of the item shapes {list(ITEM_FORMATS)} fits; "
        "pass item_format= with a shape that does"
    )


def _shape_of(reply: str) -> str | None:
    """A guess at the item shape: the reply pattern with its groups as placeholders, simple escapes undone.

    ``CH(?P<channel>\\d+)\\s+(?P<value>\\S+)`` gives ``CH{channel} {value}``. Only a
    guess: the caller keeps it only if the pattern parses its samples back.
    """
    text = reply.replace("{", "{{").replace("}", "}}")
    for name in ("channel", "value"):
        start = text.find(f"(?P<{name}>")
        if start < 0:
            continue
        depth, i = 0, start
        while i < len(text):
            if text[i] == "\\":
                i += 2
                continue
            depth += {"(": 1, ")": -1}.get(text[i], 0)
            if depth == 0:
                break
            i += 1
        else:
            return None
        text = text[:start] + "{" + name + "}" + text[i + 1 :]
    for regex, plain in ((r"\s+", " "), (r"\s*", ""), (r"\s", " "), (" +", " ")):
        text = text.replace(regex, plain)
    return re.sub(r"\\(.)", r"\1", text)


def _parses_back(
    settings: SerialSensorSettings,
    pattern: re.Pattern[str],
    item_format: str,
    channel: str,
    value: float,
) -> bool:
    item = item_format.format(channel=channel, value=repr(value))
    if settings.item_separator and settings.item_separator in item:
        return False
    try:
        parsed: dict[str, float] = parse_values(settings, pattern, item, [channel])
    except DriverProtocolError:
        return False
    return parsed == {channel: value}
