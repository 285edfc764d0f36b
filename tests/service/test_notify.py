"""SystemdNotifier against real unix datagram sockets bound by the test, as systemd binds them."""

from __future__ import annotations

import contextlib
import logging
import os
import socket
import uuid
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace

import pytest

from compd.service.notify import SystemdNotifier, SystemdTicks


@pytest.fixture
def path_socket(tmp_path: Path) -> Iterator[tuple[socket.socket, str]]:
    """A datagram socket bound to a file path, and the NOTIFY_SOCKET value naming it."""
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    path = str(tmp_path / "notify.sock")
    sock.bind(path)
    sock.settimeout(60.0)  # a hang guard: the datagram is sent at once
    yield sock, path
    sock.close()


@pytest.fixture
def abstract_socket() -> Iterator[tuple[socket.socket, str]]:
    """A datagram socket in the abstract namespace, and its ``@name`` NOTIFY_SOCKET value."""
    name = f"compd-test-{uuid.uuid4().hex}"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind("\0" + name)
    sock.settimeout(60.0)  # a hang guard: the datagram is sent at once
    yield sock, "@" + name
    sock.close()


def received(sock: socket.socket) -> bytes:
    return sock.recv(4096)


def test_messages_reach_a_path_socket_as_exact_datagrams(path_socket):
    """ready, watchdog, status and stopping each send one datagram with systemd's exact text."""
    sock, address = path_socket
    with SystemdNotifier({"NOTIFY_SOCKET": address}) as notifier:
        assert notifier.enabled
        assert notifier.ready()
        assert received(sock) == b"READY=1"
        assert notifier.watchdog()
        assert received(sock) == b"WATCHDOG=1"
        assert notifier.status("compensating, 3 outputs")
        assert received(sock) == b"STATUS=compensating, 3 outputs"
        assert notifier.stopping()
        assert received(sock) == b"STOPPING=1"


def test_messages_reach_an_abstract_socket(abstract_socket):
    """An ``@name`` NOTIFY_SOCKET is the abstract socket ``\\0name``."""
    sock, address = abstract_socket
    notifier = SystemdNotifier({"NOTIFY_SOCKET": address})
    assert notifier.ready(status="ready: model seed000")
    assert received(sock) == b"READY=1\nSTATUS=ready: model seed000"
    assert notifier.watchdog()
    assert received(sock) == b"WATCHDOG=1"
    notifier.close()


def test_status_is_one_line(path_socket):
    """A status text with newlines is sent as one STATUS line, so it cannot inject other keys."""
    sock, address = path_socket
    notifier = SystemdNotifier({"NOTIFY_SOCKET": address})
    notifier.status("hold\nREADY=1")
    assert received(sock) == b"STATUS=hold READY=1"
    notifier.close()


def test_reloading_carries_the_monotonic_time(path_socket):
    """RELOADING=1 is sent with MONOTONIC_USEC, which systemd >= 253 requires."""
    sock, address = path_socket
    notifier = SystemdNotifier({"NOTIFY_SOCKET": address})
    notifier.reloading()
    fields = received(sock).decode().split("\n")
    assert fields[0] == "RELOADING=1"
    assert fields[1].startswith("MONOTONIC_USEC=") and int(fields[1].split("=")[1]) > 0
    notifier.close()


def test_without_notify_socket_every_call_is_a_no_op():
    """Outside systemd nothing is sent and nothing fails."""
    notifier = SystemdNotifier({})
    assert not notifier.enabled
    assert notifier.watchdog_interval_s is None
    assert not notifier.ready()
    assert not notifier.watchdog()
    assert not notifier.status("x")
    assert not notifier.stopping()


def test_watchdog_interval_is_half_the_unit_timeout():
    """WATCHDOG_USEC=10 s gives a 10 s timeout and a 5 s ping interval."""
    notifier = SystemdNotifier({"NOTIFY_SOCKET": "@x", "WATCHDOG_USEC": "10000000"})
    assert notifier.watchdog_timeout_s == pytest.approx(10.0)
    assert notifier.watchdog_interval_s == pytest.approx(5.0)


def test_watchdog_meant_for_another_process_is_off():
    """WATCHDOG_PID naming another process (an inherited environment) turns the watchdog off."""
    env = {"WATCHDOG_USEC": "10000000", "WATCHDOG_PID": str(os.getpid() + 1)}
    assert SystemdNotifier(env).watchdog_interval_s is None
    env["WATCHDOG_PID"] = str(os.getpid())
    assert SystemdNotifier(env).watchdog_interval_s == pytest.approx(5.0)


def test_a_vanished_socket_is_logged_once_and_never_raises(tmp_path, caplog):
    """Sending to a socket that is gone returns False, logs one error, then only debug lines."""
    notifier = SystemdNotifier({"NOTIFY_SOCKET": str(tmp_path / "gone.sock")})
    with caplog.at_level(logging.DEBUG, logger="compd.service.notify"):
        assert not notifier.watchdog()
        assert not notifier.watchdog()
        assert not notifier.watchdog()
    levels = [record.levelno for record in caplog.records]
    assert levels == [logging.ERROR, logging.DEBUG, logging.DEBUG]


def test_recovery_after_a_failure_is_logged(tmp_path, caplog):
    """When the socket comes back, the next ping is delivered and the recovery logged at info."""
    path = tmp_path / "late.sock"
    notifier = SystemdNotifier({"NOTIFY_SOCKET": str(path)})
    with caplog.at_level(logging.INFO, logger="compd.service.notify"):
        assert not notifier.watchdog()
        with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as sock:
            sock.bind(str(path))
            sock.settimeout(60.0)  # a hang guard: the datagram is sent at once
            assert notifier.watchdog()
            assert sock.recv(64) == b"WATCHDOG=1"
    assert [r.levelno for r in caplog.records] == [logging.ERROR, logging.INFO]
    notifier.close()


def test_a_full_queue_drops_pings_instead_of_blocking(path_socket):
    """Pings to a receiver that never reads fail fast (non-blocking) rather than stall the loop."""
    _, address = path_socket
    notifier = SystemdNotifier({"NOTIFY_SOCKET": address})
    results = [notifier.watchdog() for _ in range(2000)]  # far beyond a datagram queue's length
    assert results[0] and not results[-1]
    notifier.close()


def test_a_bad_notify_socket_value_disables_notification(caplog):
    """A NOTIFY_SOCKET that is neither a path nor @name is logged and ignored."""
    with caplog.at_level(logging.ERROR, logger="compd.service.notify"):
        notifier = SystemdNotifier({"NOTIFY_SOCKET": "vsock:2:1234"})
    assert not notifier.enabled and not notifier.ready()
    assert "NOTIFY_SOCKET" in caplog.text


def _tick(ticks: int, started_real_s: float, *, on_time: bool = True) -> SimpleNamespace:
    """What SystemdTicks reads of a tick's snapshot: its count, real start and whether on time."""
    return SimpleNamespace(
        ticks=ticks, first=ticks == 1, model=None, started_real_s=started_real_s, on_time=on_time
    )


def _pings(sock: socket.socket) -> list[bytes]:
    """Every WATCHDOG=1 datagram waiting on ``sock`` (the rest dropped)."""
    sock.setblocking(False)
    got = []
    with contextlib.suppress(BlockingIOError):
        while True:
            got.append(sock.recv(4096))
    return [g for g in got if g == b"WATCHDOG=1"]


def test_the_watchdog_is_pinged_every_quarter_timeout_not_every_tick(path_socket):
    """WatchdogSec=10 s, a tick each 1 s: a ping at 0, 3, 6 and 9 s (each the first tick 2.5 s
    after the last ping); a late tick does not ping, the next healthy one does."""
    sock, address = path_socket
    notifier = SystemdNotifier({"NOTIFY_SOCKET": address, "WATCHDOG_USEC": "10000000"})
    ticks = SystemdTicks(notifier, status_every_ticks=10**9)
    pinged = []
    for second in range(10):
        ticks.on_tick(_tick(second + 1, float(second)))
        pinged += [second] * len(_pings(sock))
    assert pinged == [0, 3, 6, 9]
    ticks.on_tick(_tick(11, 12.0, on_time=False))
    assert _pings(sock) == []
    ticks.on_tick(_tick(12, 13.0))
    assert _pings(sock) == [b"WATCHDOG=1"]
    notifier.close()


def test_without_a_watchdog_nothing_is_pinged(path_socket):
    """A unit without WatchdogSec= (no WATCHDOG_USEC) gets READY=1 and no WATCHDOG=1 at all."""
    sock, address = path_socket
    notifier = SystemdNotifier({"NOTIFY_SOCKET": address})
    ticks = SystemdTicks(notifier, status_every_ticks=10**9)
    for second in range(5):
        ticks.on_tick(_tick(second + 1, float(second)))
    assert _pings(sock) == []
    notifier.close()
