"""A state directory compd cannot save into is said beside the offsets, not only once in the journal:
``compd status`` (and ``--json``), ``/metrics`` and systemd's status line say it while it lasts."""

from __future__ import annotations

import asyncio
import socket
from pathlib import Path

from prometheus_client.parser import text_string_to_metric_families

from compd.cli.status import state_line
from compd.service.daemon import Service
from compd.service.http.metrics import ServiceMetrics
from compd.service.loop.clock import VirtualClock
from compd.service.loop.compensator import TickRecord
from compd.service.notify import SystemdNotifier

from .daemon_setup import notify_socket, status_lines, write_config


def _run(
    tmp_path: Path, sock: socket.socket, path: str, *, broken: bool
) -> tuple[Service, list[str]]:
    """The bundled simulated config for 60 s, saving every 10 ticks, with ``state.json`` made a
    directory at the first tick where ``broken`` (every save fails: the rename cannot replace it);
    the service, and systemd's status lines."""
    config = write_config(tmp_path, {"state": {"save_every_ticks": 10}, "live_every_ticks": 10})
    state_file = config.state_dir / "state.json"
    lines: list[str] = []

    def break_state(record: TickRecord) -> None:
        lines.extend(status_lines(sock))
        if broken and not state_file.is_dir():
            state_file.unlink(missing_ok=True)
            state_file.mkdir(parents=True)

    service = Service(
        config,
        clock=VirtualClock(),
        control=False,
        notifier=SystemdNotifier({"NOTIFY_SOCKET": path}),
        on_tick=break_state,
        background_saves=False,
    )
    asyncio.run(service.run(duration_s=60.0))
    return service, lines


def _state_saved_metric(service: Service) -> float:
    text = ServiceMetrics(service).render()[0].decode()
    for family in text_string_to_metric_families(text):
        if family.name == "compd_state_saved":
            return family.samples[0].value
    raise AssertionError("no compd_state_saved in /metrics")


def test_saves_that_fail_are_in_the_status_the_metrics_and_systemds_line(tmp_path: Path) -> None:
    """Every save refused: status says saving false with the error, ``compd status`` prints a red
    "state not saved" line, ``compd_state_saved`` is 0, and systemd's status line says it too."""
    with notify_socket() as (sock, path):
        service, statuses = _run(tmp_path, sock, path, broken=True)
    state = service.status()["state"]
    assert state["saving"] is False and "Is a directory" in state["error"], state
    line = state_line(service.status())
    assert line is not None and line.plain.startswith(
        f"  state not saved in {service.config.state_dir} ("
    )
    assert line.plain.endswith("a restart resumes from an older state")
    assert _state_saved_metric(service) == 0
    assert statuses and "state not saved in" in statuses[-1], statuses


def test_saves_that_work_say_nothing(tmp_path: Path) -> None:
    """Saves that succeed: saving true, no status line, ``compd_state_saved`` 1, and systemd's line
    says nothing of the state."""
    with notify_socket() as (sock, path):
        service, statuses = _run(tmp_path, sock, path, broken=False)
    assert service.status()["state"]["saving"] is True
    assert state_line(service.status()) is None
    assert _state_saved_metric(service) == 1
    assert statuses and "; status word 0 (ok)" in statuses[-1], statuses
    assert "state not saved" not in statuses[-1] and service.not_assured()[0].startswith(
        "not assured on Y"
    )
