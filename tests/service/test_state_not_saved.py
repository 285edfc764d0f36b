"""A state directory compd cannot save into is said beside the offsets, not only once in the journal:
``compd status`` (and ``--json``), ``/metrics`` and systemd's status line say it while it lasts."""

from __future__ import annotations

import asyncio
import shutil
import socket
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest
from prometheus_client.parser import text_string_to_metric_families

from compd.cli.status import state_line
from compd.service.daemon import Service
from compd.service.http.metrics import ServiceMetrics
from compd.service.loop.clock import VirtualClock
from compd.service.loop.compensator import TickRecord
from compd.service.notify import SystemdNotifier

from .daemon_setup import write_config


@pytest.fixture
def notify_socket() -> Iterator[tuple[socket.socket, str]]:
    """A datagram socket standing for systemd's, on a path short enough for AF_UNIX."""
    directory = tempfile.mkdtemp(prefix="compd-", dir="/tmp")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    path = str(Path(directory) / "n.sock")
    sock.bind(path)
    sock.setblocking(False)
    yield sock, path
    sock.close()
    shutil.rmtree(directory)


def _statuses(sock: socket.socket) -> list[str]:
    """Every tick's ``STATUS=`` line waiting on ``sock``, in order (not start's or shutdown's)."""
    lines = []
    while True:
        try:
            datagram = sock.recv(65536).decode()
        except BlockingIOError:
            return [line for line in lines if "; status word " in line]
        lines += [f[len("STATUS=") :] for f in datagram.split("\n") if f.startswith("STATUS=")]


def _run(tmp_path: Path, notifier: SystemdNotifier, *, broken: bool) -> Service:
    """The bundled simulated config for 60 s, saving every 10 ticks, with ``state.json`` made a
    directory at the first tick where ``broken`` (every save fails: the rename cannot replace it)."""
    config = write_config(tmp_path, {"state": {"save_every_ticks": 10}, "live_every_ticks": 10})
    state_file = config.state_dir / "state.json"

    def break_state(record: TickRecord) -> None:
        if broken and not state_file.is_dir():
            state_file.unlink(missing_ok=True)
            state_file.mkdir(parents=True)

    service = Service(
        config,
        clock=VirtualClock(),
        control=False,
        notifier=notifier,
        on_tick=break_state,
        background_saves=False,
    )
    asyncio.run(service.run(duration_s=60.0))
    return service


def _state_saved_metric(service: Service) -> float:
    text = ServiceMetrics(service).render()[0].decode()
    for family in text_string_to_metric_families(text):
        if family.name == "compd_state_saved":
            return family.samples[0].value
    raise AssertionError("no compd_state_saved in /metrics")


def test_saves_that_fail_are_in_the_status_the_metrics_and_systemds_line(
    tmp_path: Path, notify_socket: tuple[socket.socket, str]
) -> None:
    """Every save refused: status says saving false with the error, ``compd status`` prints a red
    "state not saved" line, ``compd_state_saved`` is 0, and systemd's status line says it too."""
    sock, path = notify_socket
    service = _run(tmp_path, SystemdNotifier({"NOTIFY_SOCKET": path}), broken=True)
    state = service.status()["state"]
    assert state["saving"] is False and "Is a directory" in state["error"], state
    line = state_line(service.status())
    assert line is not None and line.plain.startswith(
        f"  state not saved in {service.config.state_dir} ("
    )
    assert line.plain.endswith("a restart resumes from an older state")
    assert _state_saved_metric(service) == 0
    statuses = _statuses(sock)
    assert statuses and "state not saved in" in statuses[-1], statuses


def test_saves_that_work_say_nothing(
    tmp_path: Path, notify_socket: tuple[socket.socket, str]
) -> None:
    """Saves that succeed: saving true, no status line, ``compd_state_saved`` 1, and systemd's line
    reads offsets, status word and level alone: ``Z +... um; status word 0 (ok)``."""
    sock, path = notify_socket
    service = _run(tmp_path, SystemdNotifier({"NOTIFY_SOCKET": path}), broken=False)
    assert service.status()["state"]["saving"] is True
    assert state_line(service.status()) is None
    assert _state_saved_metric(service) == 1
    statuses = _statuses(sock)
    assert statuses and statuses[-1].endswith("; status word 0 (ok)"), statuses
