"""LinuxCNC: read signals from HAL, write offsets to the axes' external offsets.

compd is a userspace HAL component here: each signal it reads is an IN pin
``<component>.<address>`` linked to a HAL signal, and each axis offset goes
to LinuxCNC's external offsets (``axis.L.eoffset-counts``, ``-scale``,
``-enable``). LinuxCNC itself moves the axis to the offset, no faster than
``[AXIS_L]OFFSET_AV_RATIO`` of the axis's ``MAX_VELOCITY`` and
``MAX_ACCELERATION`` allow, so even a stepped offset ramps; compd's own
slew limit (``max_rate_um_per_s``) comes first and is far slower.

Addresses::

    axis.z                 the Z axis's external offset: written in counts,
                           read back as the counts LinuxCNC holds
    spindle-speed          a HAL signal
    spindle.0.speed-out    an output pin: the signal it drives (a new signal
                           ``compd:spindle.0.speed-out`` when it drives none)

Offsets are counts: ``encoding: {type: int, scale: 10}`` with the default
``count_um: 0.1``; the driver sets ``eoffset-scale`` to ``count_um`` in the
machine's ``linear_units`` (0.0001 mm). An axis needs
``[AXIS_L]OFFSET_AV_RATIO`` above 0, or LinuxCNC ignores its offset; with
``ini_file`` set, the driver refuses to write to such an axis.

Why a helper process: LinuxCNC's ``hal`` module is a C extension built for
Debian's ``/usr/bin/python3``, not for the interpreter compd runs in (a venv
of another build, perhaps another minor version). And a userspace HAL
component lives in the process that created it: ``halcmd unload all``, run
when LinuxCNC shuts down, SIGTERMs that process, and a HAL call after the
shared memory went away can crash it. So the component lives in a small
helper (``linuxcnc_hal.py``, stdlib and ``hal`` only) run under ``python``
from the settings, speaking one JSON line per request over its stdin and
stdout. LinuxCNC stopping ends the helper; this driver sees the pipe close
and raises :class:`~compd.errors.DriverDisconnectedError`, and the link
reconnects when LinuxCNC is back. ``halcmd setp``/``getp`` per value would
need no helper, but costs a process per call and gives LinuxCNC no
component to show, wire or unload.
"""

from __future__ import annotations

import asyncio
import collections
import configparser
import contextlib
import json
import math
import re
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    StrictBool,
    StrictFloat,
    TypeAdapter,
    ValidationError,
)

from compd.drivers.base import HostProblem, RawReading
from compd.errors import (
    DriverDisconnectedError,
    DriverError,
    DriverProtocolError,
    DriverTimeoutError,
)

HELPER = Path(__file__).with_name("linuxcnc_hal.py")
_AXIS = re.compile(r"axis\.[xyzabcuvw]")
# HAL names are at most 47 characters; the pin is "<component>.<address>".
_HAL_NAME = re.compile(r"[A-Za-z0-9_.:-]{1,41}")
_S32 = (-(2**31), 2**31 - 1)
_UM_PER_UNIT = {"mm": 1000.0, "inch": 25400.0}
_ENDED = "the HAL helper ended (LinuxCNC shut down, or halcmd unload removed the component)"


class _Done(BaseModel):
    """A served request's reply line: ``{"ok": PAYLOAD}`` (the payload checked per request)."""

    model_config = ConfigDict(extra="forbid")
    ok: Any


class _Refused(BaseModel):
    """A refused request's reply line: ``{"error": TEXT, "kind": KIND}``."""

    model_config = ConfigDict(extra="forbid")
    error: str
    kind: str = "disconnected"


#: Every reply line the helper may send (``linuxcnc_hal.py``'s docstring). pydantic's
#: JSON parser bounds nesting: a line of 60,000 ``[`` is a validation error, not a RecursionError.
_REPLY: TypeAdapter[_Done | _Refused] = TypeAdapter(_Done | _Refused)
#: A HAL value: a bit, an s32 or u32, or a float.
_HalValue = StrictBool | Annotated[int, Field(strict=True, ge=_S32[0], le=2**32 - 1)] | StrictFloat
#: The payload of each request's ``ok``: the values read by address, or nothing.
_READ: TypeAdapter[dict[str, bool | int | float]] = TypeAdapter(dict[str, _HalValue])
_NOTHING: TypeAdapter[None] = TypeAdapter(None)


class LinuxCncSettings(BaseModel):
    """``drivers.<name>.settings`` of a ``type: linuxcnc`` driver."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    component: str = Field(
        default="compd",
        pattern=r"^[A-Za-z][A-Za-z0-9_-]{0,4}$",
        description="HAL component name (pins <component>.<address>), at most 5 characters",
    )
    python: str = Field(
        default="/usr/bin/python3", description="the Python that LinuxCNC's hal module is for"
    )
    linear_units: Literal["mm", "inch"] = Field(
        default="mm", description="[TRAJ]LINEAR_UNITS of the machine"
    )
    count_um: float = Field(
        default=0.1, gt=0, description="um per offset count: 1 / the outputs' encoding.scale"
    )
    ini_file: str | None = Field(
        default=None, description="the machine's INI file: axes without OFFSET_AV_RATIO refused"
    )
    request_timeout_s: float = Field(default=1.0, gt=0)


class LinuxCncDriver:
    """A userspace HAL component in a helper process; see the module docstring."""

    settings_model = LinuxCncSettings
    #: Shown in config errors as the fix for a bad address.
    address_syntax = (
        "as axis.L for an offset (L one of x y z a b c u v w), or a HAL signal or "
        "output pin name to read (e.g. spindle.0.speed-out), at most 41 characters"
    )

    def __init__(
        self, settings: LinuxCncSettings, *, now: Callable[[], float], base_dir: Path
    ) -> None:
        self.settings = settings
        self._ini = None if settings.ini_file is None else base_dir / settings.ini_file
        self._process: asyncio.subprocess.Process | None = None
        self._lock: asyncio.Lock | None = None
        self._stderr: collections.deque[str] = collections.deque(maxlen=20)
        self._stderr_task: asyncio.Task[None] | None = None
        self._checked_axes: set[str] = set()

    @staticmethod
    def validate_address(address: str, *, writable: bool, settings: object = None) -> None:
        """Config-time check of one address; ValueError names what is wrong."""
        if writable:
            if not _AXIS.fullmatch(address):
                raise ValueError(f"{address!r}: LinuxCNC offsets go to an axis: axis.x .. axis.w")
        elif not _HAL_NAME.fullmatch(address):
            raise ValueError(f"{address!r} is not a HAL name of at most 41 characters")

    @staticmethod
    def raw_range(address: str, settings: LinuxCncSettings) -> tuple[int, int] | None:
        """An axis offset is an s32 count; other addresses are not written."""
        return _S32 if _AXIS.fullmatch(address) else None

    @staticmethod
    def reads_back(settings: LinuxCncSettings) -> bool:
        """Yes: ``axis.L`` reads the counts HAL holds, which outlive compd and not LinuxCNC."""
        return True

    @staticmethod
    def check_host(
        settings: LinuxCncSettings, *, base_dir: Path, written: Sequence[str]
    ) -> HostProblem | None:
        """With ``ini_file``: it is readable and each axis written has an ``OFFSET_AV_RATIO`` above 0."""
        if settings.ini_file is None:
            return None
        ini = base_dir / settings.ini_file
        for address in sorted(set(written)):
            if _AXIS.fullmatch(address) and (problem := _ini_problem(ini, address[5:])):
                message, fix = problem
                return HostProblem(("ini_file",), message, fix)
        return None

    @property
    def helper_pid(self) -> int | None:
        """The helper process's id while open (tests stop it to cut the link)."""
        return None if self._process is None else self._process.pid

    async def open(self) -> None:
        await self.close()
        s = self.settings
        try:
            process = await asyncio.create_subprocess_exec(
                s.python,
                str(HELPER),
                s.component,
                stdin=asyncio.subprocess.PIPE,
                stdout=asyncio.subprocess.PIPE,
                stderr=asyncio.subprocess.PIPE,
            )
        except OSError as exc:
            raise DriverDisconnectedError(
                f"LinuxCNC: cannot run {s.python} for the HAL helper: {exc}"
            ) from exc
        self._process = process
        self._lock = asyncio.Lock()
        self._stderr.clear()
        self._stderr_task = asyncio.create_task(self._keep_stderr(process))
        scale = s.count_um / _UM_PER_UNIT[s.linear_units]
        try:
            await self._request({"open": {"scale": scale}}, _NOTHING)
        except DriverError:
            await self.close()
            raise

    async def read(self, points: Sequence[str]) -> dict[str, float]:
        return {name: float(v) for name, v in (await self._read_hal(points)).items()}

    async def read_raw(self, points: Sequence[str]) -> dict[str, RawReading]:
        """Each HAL value as the helper sent it (``true`` for a bit, ``5`` for s32/u32, ``1.25`` float)."""
        values = await self._read_hal(points)
        return {name: RawReading(json.dumps(v), float(v)) for name, v in values.items()}

    async def _read_hal(self, points: Sequence[str]) -> dict[str, Any]:
        for address in points:
            if not _HAL_NAME.fullmatch(address):
                raise DriverProtocolError(f"LinuxCNC: {address!r} is not a HAL name (<= 41 chars)")
        values: dict[str, bool | int | float] = await self._request({"read": list(points)}, _READ)
        if not values.keys() <= set(points):
            unasked = sorted(values.keys() - set(points))[:3]
            raise DriverProtocolError(f"LinuxCNC: the HAL helper answered for unasked {unasked}")
        return values

    async def write(self, values: Mapping[str, float]) -> None:
        counts = {}
        for address, value in values.items():
            if not _AXIS.fullmatch(address):
                raise DriverProtocolError(f"LinuxCNC: {address!r} is not an axis: cannot write it")
            if not math.isfinite(value) or not _S32[0] <= round(value) <= _S32[1]:
                raise DriverProtocolError(f"LinuxCNC: {address}: {value} counts do not fit s32")
            self._check_axis(address[5:])
            counts[address] = round(value)
        await self._request({"write": counts}, _NOTHING)

    async def close(self) -> None:
        process, self._process = self._process, None
        task, self._stderr_task = self._stderr_task, None
        if process is not None:
            with contextlib.suppress(Exception):  # close() never raises (Driver contract)
                if process.stdin is not None:
                    process.stdin.close()  # end of input: the helper removes its component
                try:
                    await asyncio.wait_for(process.wait(), 3.0)
                except TimeoutError:
                    process.kill()
                    await process.wait()
        if task is not None:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task

    # -- internals ----------------------------------------------------------

    async def _request(self, request: dict[str, Any], payload: TypeAdapter[Any]) -> Any:
        """Send one request line, await its reply line, check it; failures become DriverError.

        ``payload`` is the schema of the reply's ``ok``: a reply of any other
        shape is a :class:`~compd.errors.DriverProtocolError`.
        """
        process, lock = self._process, self._lock
        if process is None or lock is None:
            raise DriverDisconnectedError("LinuxCNC driver is not open")
        async with lock:
            if process.returncode is not None:
                raise DriverDisconnectedError(self._gone(_ENDED))
            assert process.stdin is not None and process.stdout is not None
            try:
                process.stdin.write(json.dumps(request).encode() + b"\n")
                await process.stdin.drain()
                line = await asyncio.wait_for(
                    process.stdout.readline(), self.settings.request_timeout_s
                )
            except TimeoutError as exc:
                # A late reply would answer the next request: drop this helper.
                process.kill()
                raise DriverTimeoutError(
                    f"LinuxCNC: no reply from the HAL helper in {self.settings.request_timeout_s} s"
                ) from exc
            except (OSError, ValueError) as exc:  # broken pipe, or a line over the limit
                raise DriverDisconnectedError(self._gone(str(exc))) from exc
        if not line:
            task = self._stderr_task  # the helper's last words, for the message
            if task is not None:
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(asyncio.shield(task), 1.0)
            raise DriverDisconnectedError(self._gone(_ENDED))
        try:
            reply = _REPLY.validate_json(line)
            if isinstance(reply, _Refused):
                kind = DriverProtocolError if reply.kind == "protocol" else DriverDisconnectedError
                raise kind(f"LinuxCNC: {reply.error}")
            return payload.validate_python(reply.ok)
        except ValidationError as exc:
            raise DriverProtocolError(
                f"LinuxCNC: the HAL helper's reply {line[:200]!r} is not a reply to "
                f"{next(iter(request))}: {_first_error(exc)}"
            ) from exc

    def _gone(self, what: str) -> str:
        tail = " | ".join(self._stderr)
        return f"LinuxCNC: {what}" + (f" ({tail})" if tail else "")

    async def _keep_stderr(self, process: asyncio.subprocess.Process) -> None:
        """Keep the helper's last lines of stderr for the error message, so its pipe never fills."""
        assert process.stderr is not None
        async for line in process.stderr:
            self._stderr.append(line.decode(errors="replace").strip())

    def _check_axis(self, axis: str) -> None:
        """With ``ini_file``: refuse an axis whose external offsets LinuxCNC would ignore."""
        if self._ini is None or axis in self._checked_axes:
            return
        problem = _ini_problem(self._ini, axis)
        if problem is not None:
            message, fix = problem
            raise DriverProtocolError(f"LinuxCNC: {message}; {fix[0].lower()}{fix[1:]}")
        self._checked_axes.add(axis)


def _ini_problem(ini_path: Path, axis: str) -> tuple[str, str] | None:
    """What keeps LinuxCNC from applying offsets to ``axis`` per its INI file, and the fix; None: nothing."""
    ini = configparser.ConfigParser(strict=False, interpolation=None, comment_prefixes="#;")
    section = f"AXIS_{axis.upper()}"
    try:
        with ini_path.open(encoding="utf-8", errors="replace") as f:
            ini.read_file(f)
        ratio = float(ini.get(section, "OFFSET_AV_RATIO", fallback="0"))
    except (OSError, configparser.Error, ValueError) as exc:
        return (
            f"cannot read {ini_path}: {exc}",
            "Give the machine's INI file as ini_file (relative paths start at the config's folder)",
        )
    if not ratio > 0:
        return (
            f"{ini_path}: [{section}]OFFSET_AV_RATIO is not above 0, so LinuxCNC ignores "
            f"external offsets on {axis.upper()}",
            f"Set it in [{section}] (e.g. OFFSET_AV_RATIO = 0.1) and restart LinuxCNC",
        )
    return None


def _first_error(exc: ValidationError) -> str:
    """The first thing pydantic found wrong, with where (``ok.<address>``) when it is inside."""
    first = exc.errors()[0]
    where = ".".join(str(part) for part in first["loc"] if part not in ("_Done", "_Refused"))
    return first["msg"] + (f" (at {where})" if where else "")
