"""The faults of the soak (:mod:`compd.sim.soak`): the seeded draw, and what each kind is made of.

Kinds, each with variants drawn with it: ``plc_reset`` (the PLC restarts
and clears its offset register), ``link_drop`` (its server gone for a while),
``garbage`` (another server on its port answering bytes that are not Modbus:
random bytes, a frame header with the wrong protocol and length, or a
connection closed at once), ``state_corrupt`` (the state file damaged between
a stop and a restart), ``bad_model`` (a model file ``load`` must refuse) and
``kill`` (the service dropped as SIGKILL leaves it: between two ticks, or in
the middle of a write, which the PLC applies and compd never hears back) and
``out_of_clamp`` (the PLC's own program puts a value outside the clamp into
the offset register: 500 um, -3000 um, or the int32 register's extremes),
``malformed`` (for a while, half the PLC's replies are well-framed Modbus
of the wrong shape: too short or too long, a byte count that lies, another
function code, an exception code no device uses, a PDU cut short) and
``slow_clients`` (for a while, hundreds of clients hold connections to the
HTTP server, the control socket or both, each having sent half a request,
while the status is asked for and ``/metrics`` scraped:
:mod:`compd.sim.soakclients`); ``sighup`` (the service told to reload, as
SIGHUP does, with its config file as it was, changed in what only a restart
applies, or broken: :mod:`compd.sim.soakreload`); and the sensor faults of
:data:`SENSOR_KINDS`, each on a model input in turn
(:mod:`compd.sim.soaksensors`): ``sensor_offset`` (a plausible wrong value,
+15 or -25 degC off the truth), ``glitch`` (60 degC for 40 s), ``stuck`` and
``wire_break`` (the reading at its type's top, 327.67, at -200, or NaN).
The state file's numbers go wrong too: ``"ticks": Infinity``, ``1e400``,
``-Infinity`` or an integer of 5,000 digits, ``"saved_at_unix_s": NaN``.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import random
import re
import struct
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

from compd.drivers.base import Driver

FAULT_KINDS = (
    "plc_reset",
    "link_drop",
    "garbage",
    "state_corrupt",
    "bad_model",
    "kill",
    "out_of_clamp",
    "malformed",
    "slow_clients",
    "sighup",
    "sensor_offset",
    "glitch",
    "stuck",
    "wire_break",
)
#: Faults that stop the service (the others strike while it runs).
RESTARTS = ("state_corrupt", "kill")
#: Faults of a model input's sensor, struck through the simulated machine's own fault injection.
SENSOR_KINDS = ("sensor_offset", "glitch", "stuck", "wire_break")
#: The faults that last a while: how long (virtual s, uniform), shorter than the shortest gap.
DURATIONS_S = {
    "link_drop": (5.0, 60.0),
    "garbage": (5.0, 30.0),
    "malformed": (5.0, 30.0),
    "slow_clients": (10.0, 60.0),
    "sensor_offset": (60.0, 115.0),
    "glitch": (40.0, 40.0),
    "stuck": (60.0, 115.0),
    "wire_break": (30.0, 115.0),
}
#: The share of the PLC's replies a ``malformed`` fault rewrites.
MALFORMED_SHARE = 0.5
#: Modbus functions whose reply PDU is ``function, byte count, data`` (the reads).
_READS = frozenset({1, 2, 3, 4})


@dataclass(frozen=True)
class Fault:
    """One fault: what, when (virtual s), which variant, and for how long (the kinds in :data:`DURATIONS_S`)."""

    at_s: float
    kind: str
    variant: str = ""
    duration_s: float = 0.0


def draw_faults(
    duration_s: float,
    seed: int,
    *,
    every_s: tuple[float, float] = (120.0, 360.0),
    kinds: Sequence[str] = FAULT_KINDS,
) -> list[Fault]:
    """Faults at intervals uniform in ``every_s``; the first ``len(kinds)`` cover every kind once."""
    rng = random.Random(seed)
    first = list(kinds)
    rng.shuffle(first)
    faults: list[Fault] = []
    t_s = rng.uniform(*every_s)
    while t_s < duration_s - 60.0:
        kind = first.pop(0) if first else rng.choice(kinds)
        variant = rng.choice(VARIANTS[kind])
        length = DURATIONS_S.get(kind)
        faults.append(Fault(t_s, kind, variant, rng.uniform(*length) if length else 0.0))
        t_s += rng.uniform(*every_s)
    return faults


def bad_models(good: bytes) -> dict[str, bytes]:
    """Model files ``load`` must refuse: a gain of 1e308, a delay of 10^6 samples, a pole at 1.2, garbage."""
    head = good.decode().partition("provenance:")[0]  # no calibration record to check against
    edits = {
        "gain_1e308": (r"num: \[[^,\]]*", "num: [1e308"),
        "nk_1e6": (r"nk: \d+", "nk: 1000000"),
        "unstable": (r"den: \[[^\]]*\]", "den: [1.0, -1.2, 0.0]"),
    }
    bad = {}
    for name, (pattern, replacement) in edits.items():
        text, n = re.subn(pattern, replacement, head, count=1)
        if n != 1:
            raise ValueError(f"the soak cannot make a {name} model from this one: no {pattern!r}")
        bad[name] = text.encode()
    bad["garbage"] = random.Random(len(head)).randbytes(4096)
    return bad


def corrupt_state(saved: bytes, variant: str) -> bytes:
    """The state file ``saved`` corrupted as ``variant`` says."""
    if variant == "garbage":
        return b"\x00garbage{" + random.Random(len(saved)).randbytes(200)
    if variant == "truncated":
        return saved[: len(saved) // 2]
    if variant == "empty":
        return b""
    try:
        doc = json.loads(saved)
    except ValueError:
        return b"{}"
    if variant == "offset_1e9":
        doc["offsets_um"] = {k: 1e9 for k in doc.get("offsets_um", {})} or {"Z": 1e9}
        return json.dumps(doc).encode()
    if variant == "offset_nan":  # NaN is not JSON, but a hand-edited file may hold it
        doc["offsets_um"] = {"Z": math.nan}
        return json.dumps(doc).encode()
    if variant in BAD_NUMBERS:  # written as text: json.dumps cannot write 1e400 or 5,000 digits
        key, text = BAD_NUMBERS[variant]
        doc[key] = _PLACE
        return json.dumps(doc).replace(json.dumps(_PLACE), text).encode()
    doc["model_sha256"] = "0" * 64  # "other_model"
    return json.dumps(doc).encode()


#: The ``state_corrupt`` variants that put a number no saved state holds into a key: the text written.
BAD_NUMBERS = {
    "ticks_infinity": ("ticks", "Infinity"),
    "ticks_1e400": ("ticks", "1e400"),
    "ticks_-infinity": ("ticks", "-Infinity"),
    "ticks_5000_digits": ("ticks", "9" * 5000),
    "saved_at_nan": ("saved_at_unix_s", "NaN"),
}
_PLACE = "<the bad number>"

VARIANTS: dict[str, tuple[str, ...]] = {
    "plc_reset": ("",),
    "link_drop": ("",),
    "garbage": ("random", "bad_header", "close"),
    "state_corrupt": (
        *("garbage", "truncated", "empty", "offset_1e9", "offset_nan", "other_model"),
        *BAD_NUMBERS,
    ),
    "bad_model": ("gain_1e308", "nk_1e6", "unstable", "garbage"),
    "kill": ("between_ticks", "mid_write"),
    "out_of_clamp": ("500um", "-3000um", "int32_max", "int32_min"),
    "malformed": ("short", "long", "byte_count", "function", "exception", "truncated"),
    "slow_clients": ("http", "socket", "both"),
    "sighup": ("unchanged", "changed", "broken"),
    "sensor_offset": ("+15", "-25"),
    "glitch": ("60",),
    "stuck": ("",),
    "wire_break": ("high", "low", "nan"),
}
#: What the PLC's program puts into the offset register (um) for each ``out_of_clamp`` variant;
#: at the bundled config's 0.1 um counts the extremes are the int32 register's.
OUT_OF_CLAMP_UM = {
    "500um": 500.0,
    "-3000um": -3000.0,
    "int32_max": (2**31 - 1) / 10,
    "int32_min": -(2**31) / 10,
}


async def garbage_server(host: str, port: int, variant: str, seed: float) -> asyncio.Server:
    """A server on ``host:port`` that answers every request with bytes that are not Modbus."""
    rng = random.Random(seed)

    async def answer(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        with contextlib.suppress(OSError, ConnectionError):
            while request_bytes := await reader.read(260):
                if variant == "random":
                    writer.write(rng.randbytes(rng.randint(1, 300)))
                elif variant == "bad_header":  # its transaction id, a wrong protocol and length
                    writer.write(request_bytes[:2] + b"\x13\x37\xff\xff" + rng.randbytes(9))
                await writer.drain()
                if variant == "close" or rng.random() < 0.3:
                    break
        writer.close()

    return await asyncio.start_server(answer, host, port, reuse_address=True)


def malformed_replies(
    variant: str, seed: float, *, share: float = MALFORMED_SHARE
) -> Callable[[bytes], bytes]:
    """A rewriter of Modbus TCP reply frames: ``share`` of them get a PDU of the wrong shape.

    The MBAP header stays consistent with the new PDU (its transaction id and
    unit id kept, its length true): the frame is well formed, the answer in it
    is not one to the request.
    """
    rng = random.Random(seed)

    def rewrite(packet: bytes) -> bytes:
        if len(packet) < 8 or rng.random() >= share:
            return packet
        pdu = _wrong_pdu(packet[7:], variant, rng)
        return packet[:4] + struct.pack(">H", len(pdu) + 1) + packet[6:7] + pdu

    return rewrite


def _wrong_pdu(pdu: bytes, variant: str, rng: random.Random) -> bytes:
    function = pdu[0]
    read = function in _READS and len(pdu) >= 2
    if variant in ("short", "long"):  # a consistent reply, for fewer or more than asked
        data = pdu[2:] if read else pdu[1:]
        data = data[:-2] if variant == "short" else data + rng.randbytes(2)
        return bytes([function, len(data) % 256]) + data if read else bytes([function]) + data
    if variant == "byte_count":  # the byte count lies (a write's echoed quantity does)
        wrong = (pdu[1] + rng.randint(1, 255)) % 256 if read else rng.randint(0, 255)
        return pdu[:1] + bytes([wrong]) + pdu[2:] if read else pdu[:-1] + bytes([wrong])
    if variant == "function":
        other = rng.choice([f for f in range(1, 128) if f != function])
        return bytes([other]) + pdu[1:]
    if variant == "exception":  # codes no device uses
        return bytes([function | 0x80, rng.choice([0, 9, 12, 0x55, 0xFF])])
    return pdu[: rng.randint(0, 1)]  # "truncated"


class DyingDriver:
    """``driver``, but its next write is its last: the PLC applies it, then the service hangs.

    ``die()`` is asked after that write: True, and the write never returns (a
    ``mid_write`` kill: the soak kills the service meanwhile); False, and it
    was an ordinary write (the service was stopped by another fault first).
    """

    def __init__(self, driver: Driver, die: Callable[[], bool]) -> None:
        self.driver = driver
        self.die = die

    async def open(self) -> None:
        await self.driver.open()

    async def read(self, points: Sequence[str]) -> dict[str, float]:
        return await self.driver.read(points)

    async def write(self, values: Mapping[str, float]) -> None:
        await self.driver.write(values)
        if self.die():
            await asyncio.Event().wait()  # frozen until killed

    async def close(self) -> None:
        await self.driver.close()
