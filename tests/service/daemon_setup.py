"""Shared set-up for the daemon's tests: the bundled simulated config in a temporary directory, run on virtual time."""

from __future__ import annotations

import asyncio
import contextlib
import copy
import shutil
import socket
import tempfile
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import yaml

from compd.files.yamlplace import resolve_path
from compd.service.config.loading import Config, load_config
from compd.service.daemon import Service
from compd.service.loop.clock import VirtualClock
from compd.service.loop.compensator import TickRecord

BUNDLED_SIMULATED = resolve_path("bundled:replay.yaml", Path("."))


def simulated_doc() -> dict[str, Any]:
    """The bundled ``replay.yaml`` as a dict, to be edited by a test."""
    doc: dict[str, Any] = yaml.safe_load(BUNDLED_SIMULATED.read_text())
    return doc


def merge(base: dict[str, Any], changes: Mapping[str, Any]) -> dict[str, Any]:
    """``base`` with ``changes`` merged in, nested dicts key by key."""
    out = copy.deepcopy(base)
    for key, value in changes.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), dict):
            out[key] = merge(out[key], value)
        else:
            out[key] = value
    return out


def write_config(
    directory: Path, changes: Mapping[str, Any] | None = None, *, doc: dict[str, Any] | None = None
) -> Config:
    """``doc`` (default: the bundled simulated config) with state under ``directory``, plus ``changes``."""
    doc = merge(
        simulated_doc() if doc is None else doc,
        {"state": {"directory": str(directory / "state")}, "recorder": {"enabled": False}},
    )
    doc = merge(doc, changes or {})
    path = directory / "compd.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return load_config(path)


def run(
    config: Config,
    duration_s: float,
    *,
    clock: VirtualClock | None = None,
    service: Service | None = None,
    control: bool = False,
) -> tuple[Service, list[TickRecord]]:
    """Run a service on virtual time for ``duration_s``; returns it and every tick's record."""
    records: list[TickRecord] = []
    if service is None:
        service = Service(
            config, clock=clock or VirtualClock(), control=control, on_tick=records.append
        )
    else:
        service.subscribe(records.append)
    asyncio.run(service.run(duration_s=duration_s))
    return service, records


async def ticked(service: Service, running: asyncio.Task[Any], ticks: int) -> None:
    """Yield to the loop until ``service`` has run ``ticks`` ticks, or its run ended (failed)."""
    while service.compensator.counters.ticks < ticks and not running.done():
        await asyncio.sleep(0)
    if running.done():
        running.result()  # a failed run fails the test here, instead of waiting for ever


def short_socket() -> Path:
    """A control-socket path short enough for AF_UNIX (pytest's tmp_path can exceed 108 bytes)."""
    return Path(tempfile.mkdtemp(prefix="compd-", dir="/tmp")) / "c.sock"


@contextlib.contextmanager
def notify_socket() -> Iterator[tuple[socket.socket, str]]:
    """A datagram socket standing for systemd's, on a path short enough for AF_UNIX, and its path
    (``NOTIFY_SOCKET``). Its queue holds few datagrams (``net.unix.max_dgram_qlen``, often 10):
    read it every tick (:func:`status_lines`)."""
    directory = tempfile.mkdtemp(prefix="compd-", dir="/tmp")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    path = str(Path(directory) / "n.sock")
    sock.bind(path)
    sock.setblocking(False)
    try:
        yield sock, path
    finally:
        sock.close()
        shutil.rmtree(directory)


def status_lines(sock: socket.socket) -> list[str]:
    """Every ``STATUS=`` line waiting on ``sock``, in order, a tick's (``...; status word ...``) only."""
    lines: list[str] = []
    while True:
        try:
            datagram = sock.recv(65536).decode()
        except BlockingIOError:
            return [line for line in lines if "; status word " in line]
        lines += [f[len("STATUS=") :] for f in datagram.split("\n") if f.startswith("STATUS=")]
