"""systemd service notifications (``sd_notify``): readiness, watchdog, status.

A unit with ``Type=notify`` is "started" only when the daemon says
``READY=1``, and with ``WatchdogSec=`` it is killed and restarted when the
daemon stops sending ``WATCHDOG=1``. compd pings the watchdog only while its
ticks are healthy, so a hung loop or driver becomes a restart instead of a
machine silently running without compensation.

The protocol is one datagram of ``KEY=VALUE`` lines sent to the unix socket
named by ``$NOTIFY_SOCKET`` (a path, or ``@name`` for the abstract
namespace), see ``sd_notify(3)``; it is implemented here in a few lines
rather than with a dependency. Outside systemd (``$NOTIFY_SOCKET`` unset)
every call is a no-op. A notification is a courtesy to the supervisor, never
a reason to stop compensating: sending never raises and never blocks (the
socket is non-blocking); a failure is logged once as an error, then at debug
level until a send succeeds again.
"""

from __future__ import annotations

import logging
import math
import os
import socket
import time
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING

from compd.service.loop.safety import Level
from compd.service.loop.signals import Health

if TYPE_CHECKING:
    from compd.service.loop.snapshot import TickSnapshot

log = logging.getLogger(__name__)


class SystemdNotifier:
    """Send ``sd_notify`` messages to the service manager named by the environment.

    Parameters
    ----------
    environ:
        Where to read ``NOTIFY_SOCKET``, ``WATCHDOG_USEC`` and
        ``WATCHDOG_PID`` (default: ``os.environ``).

    Attributes
    ----------
    enabled:
        True when ``$NOTIFY_SOCKET`` names a socket to notify.
    watchdog_timeout_s:
        ``WATCHDOG_USEC / 1e6``, the unit's ``WatchdogSec=`` in s, or None when
        the watchdog is off (unset, or ``WATCHDOG_PID`` names another process).
    watchdog_interval_s:
        The longest time between two :meth:`watchdog` calls, in s: half the
        timeout, as ``sd_watchdog_enabled(3)`` recommends; None when off.
    """

    def __init__(self, environ: Mapping[str, str] | None = None) -> None:
        env = os.environ if environ is None else environ
        self._address = _socket_address(env.get("NOTIFY_SOCKET", ""))
        self.enabled = self._address is not None
        self.watchdog_timeout_s = _watchdog_timeout_s(env)
        self.watchdog_interval_s = (
            None if self.watchdog_timeout_s is None else self.watchdog_timeout_s / 2.0
        )
        self._socket: socket.socket | None = None
        self._failing = False

    def ready(self, status: str | None = None) -> bool:
        """``READY=1``: start-up is complete (config and model loaded, first tick done)."""
        return self.notify("READY=1", *_status(status))

    def watchdog(self) -> bool:
        """``WATCHDOG=1``: the loop is alive and healthy; call at least every ``watchdog_interval_s``."""
        return self.notify("WATCHDOG=1")

    def status(self, text: str) -> bool:
        """``STATUS=text``: one line shown by ``systemctl status`` (newlines become spaces)."""
        return self.notify(*_status(text))

    def reloading(self, status: str | None = None) -> bool:
        """``RELOADING=1``: a reload (e.g. of the model) has begun; send :meth:`ready` when done.

        ``MONOTONIC_USEC`` (``CLOCK_MONOTONIC`` in us) is sent with it, as
        systemd >= 253 requires to match the reload to its request.
        """
        now_us = time.clock_gettime_ns(time.CLOCK_MONOTONIC) // 1000
        return self.notify("RELOADING=1", f"MONOTONIC_USEC={now_us}", *_status(status))

    def stopping(self, status: str | None = None) -> bool:
        """``STOPPING=1``: shutdown has begun (offsets are being cleared)."""
        return self.notify("STOPPING=1", *_status(status))

    def notify(self, *fields: str) -> bool:
        """Send ``fields`` as one datagram of newline-separated ``KEY=VALUE`` lines.

        Returns True when the datagram was sent, False when disabled or when
        sending failed (logged; never raised).
        """
        if self._address is None:
            return False
        message = "\n".join(fields).encode("utf-8", errors="replace")
        try:
            if self._socket is None:
                self._socket = socket.socket(
                    socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC
                )
                # A full receive queue must cost a lost ping, not a stalled tick.
                self._socket.setblocking(False)
            self._socket.sendto(message, self._address)
        except OSError as exc:
            self._failed(exc, message)
            return False
        if self._failing:
            self._failing = False
            log.info("systemd notification works again (socket %s)", self._printable)
        return True

    def close(self) -> None:
        """Close the socket; a later notification opens a new one."""
        if self._socket is not None:
            self._socket.close()
            self._socket = None

    def __enter__(self) -> SystemdNotifier:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    @property
    def _printable(self) -> str:
        address = self._address or ""
        return "@" + address[1:] if address.startswith("\0") else address

    def _failed(self, exc: OSError, message: bytes) -> None:
        level = logging.DEBUG if self._failing else logging.ERROR
        self._failing = True
        log.log(
            level,
            "cannot notify systemd through %s (%s); sent %r. "
            "Compensation continues; the unit's watchdog may restart compd",
            self._printable,
            exc,
            message,
        )
        self.close()  # a fresh socket next time, in case this one is broken


def _socket_address(text: str) -> str | None:
    """``$NOTIFY_SOCKET`` as an ``AF_UNIX`` address; ``@name`` is abstract (a leading NUL).

    Other forms (``vsock:``, relative paths) are not for a local daemon:
    they are logged and notification is off.
    """
    if not text:
        return None
    if text.startswith("@"):
        return "\0" + text[1:]
    if text.startswith("/"):
        return text
    log.error("NOTIFY_SOCKET=%r is not a unix socket path or @name; not notifying systemd", text)
    return None


def _watchdog_timeout_s(env: Mapping[str, str]) -> float | None:
    """``WATCHDOG_USEC`` in s, if it is meant for this process (``sd_watchdog_enabled(3)``)."""
    usec = env.get("WATCHDOG_USEC", "")
    pid = env.get("WATCHDOG_PID", "")
    if pid and pid != str(os.getpid()):
        return None  # inherited from a parent that is the watched process
    try:
        value = int(usec)
    except ValueError:
        if usec:
            log.error("WATCHDOG_USEC=%r is not a whole number of us; watchdog off", usec)
        return None
    return value / 1e6 if value > 0 else None


def _status(text: str | None) -> tuple[str, ...]:
    if text is None:
        return ()
    return ("STATUS=" + " ".join(text.splitlines()),)


class SystemdTicks:
    """The loop's subscriber that keeps systemd told: ready after the first tick, the watchdog, a status line.

    The watchdog is pinged only for a tick that finished within its period, so a
    loop that can no longer keep its deadlines (or hangs in I/O) stops pinging
    and systemd restarts it. A machine that is merely unreachable (PLC off at
    night) still gets healthy ticks: freezing the offsets is right there, and
    restarting would not help. It is pinged at the first healthy tick a
    quarter of the watchdog's timeout after the last ping (half the interval
    ``sd_watchdog_enabled(3)`` asks for, so one late tick costs nothing), not
    every tick: each ping wakes systemd (PID 1). Without a watchdog
    (``WatchdogSec=`` unset) nothing is pinged.
    """

    name = "systemd"

    def __init__(
        self,
        notifier: SystemdNotifier,
        *,
        status_every_ticks: int,
        notes: Callable[[], Sequence[str]] = tuple,
    ) -> None:
        self.notifier = notifier
        self.status_every_ticks = status_every_ticks
        #: What else the status line must say, beside the tick's own (the state not saved).
        self.notes = notes
        self._next_ping_real_s = -math.inf

    def on_tick(self, snapshot: TickSnapshot) -> None:
        if snapshot.first:
            self.notifier.ready(
                "recording (a data logger: nothing is written)"
                if snapshot.model is None
                else f"compensating with {snapshot.model.name}"
            )
        interval_s = self.notifier.watchdog_interval_s
        if (
            snapshot.on_time
            and interval_s is not None
            and snapshot.started_real_s >= self._next_ping_real_s
        ):
            self.notifier.watchdog()
            self._next_ping_real_s = snapshot.started_real_s + interval_s / 2.0
        if snapshot.ticks % self.status_every_ticks == 0:
            self.notifier.status(systemd_summary(snapshot, self.notes()))


def systemd_summary(snapshot: TickSnapshot, notes: Sequence[str] = ()) -> str:
    """One line for ``systemctl status``: the offsets, the status word and its level, and what is
    not OK.

    ``Z +0.16 um; status word 0 (ok)`` while all is well; otherwise each axis whose
    offset the tick did not get acknowledged is marked ``not written`` (the PLC holds
    another), and the line names the inputs not ``ok`` (held, estimated: a stand-in,
    faulted), the axes outside their envelope and ``notes`` (e.g. the state not saved):
    the line ``systemctl status`` shows must not read as all well when it is not.
    """
    record = snapshot.record
    offsets = ", ".join(
        f"{axis} {value:+.2f} um"
        + ("" if math.isfinite(record.acknowledged_um.get(axis, math.nan)) else " not written")
        for axis, value in record.offsets_um.items()
    )
    level = Level(record.status & 0b11).name.lower()
    said = [
        f"{name} {health.name.lower()}"
        for name, health in record.health.items()
        if health is not Health.OK
    ]
    said += [f"{axis} outside its envelope" for axis in record.outside_envelope]
    said += notes
    tail = f": {'; '.join(said)}" if said else ""
    return f"{offsets}; status word {record.status} ({level}){tail}"
