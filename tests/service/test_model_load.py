"""`load` over the control socket: checked off the event loop, bytes from the client only, for allowed peers only."""

from __future__ import annotations

import asyncio
import os
import threading
import time
from pathlib import Path
from typing import Any

import pytest

from compd.errors import ConfigFileError
from compd.service.control import modelload
from compd.service.control.modelload import load_request, startup_slots
from compd.service.control.socket import request
from compd.service.daemon import Service
from compd.service.loop.clock import VirtualClock
from compd.service.store.state import install_model_bytes

from .daemon_setup import short_socket, ticked, write_config
from .test_service import bad_and_good_models

#: A give-up bound for waits on another thread, never an assertion on elapsed time.
GIVE_UP_S = 30.0


def daemon(tmp_path: Path, changes: dict[str, Any] | None = None) -> Service:
    config = write_config(tmp_path, {"control_socket": str(short_socket()), **(changes or {})})
    return Service(config, clock=VirtualClock(), control=True)


def test_the_ticks_go_on_while_a_load_is_checked(tmp_path, monkeypatch):
    """While the daemon checks a model (here held until the loop has ticked 5 times), ticks and heartbeat go on."""
    _, good = bad_and_good_models(tmp_path)
    service = daemon(tmp_path)
    ticks_during_check: list[int] = []
    check = modelload.slot_from_bytes

    def slow_check(*args: Any) -> Any:
        counters = service.compensator.counters
        start = counters.ticks
        for _ in range(int(GIVE_UP_S / 0.01)):
            if counters.ticks >= start + 5:
                break
            time.sleep(0.01)
        ticks_during_check.append(counters.ticks - start)
        return check(*args)

    monkeypatch.setattr(modelload, "slot_from_bytes", slow_check)
    replies = {}

    async def scenario() -> None:
        task = asyncio.create_task(service.run())
        await ticked(service, task, 10)
        heartbeat = service.compensator.heartbeat
        replies["load"] = await request(
            service.config.control_socket,
            load_request(good.read_bytes(), good),
            timeout_s=GIVE_UP_S,
        )
        replies["heartbeat_moved"] = service.compensator.heartbeat != heartbeat
        service.stop()
        await task

    asyncio.run(scenario())
    assert replies["load"]["ok"] and replies["load"]["model"] == "retuned"
    assert ticks_during_check[0] >= 5 and replies["heartbeat_moved"]


def test_stop_is_served_while_a_load_is_being_checked(tmp_path, monkeypatch):
    """A stop (SIGTERM's handler) during a check that never ends still shuts the daemon down cleanly."""
    _, good = bad_and_good_models(tmp_path)
    service = daemon(tmp_path)
    release = threading.Event()
    entered = threading.Event()

    def stuck_check(*args: Any) -> Any:
        entered.set()
        release.wait(GIVE_UP_S)
        raise AssertionError("released only when the test gives up")

    monkeypatch.setattr(modelload, "slot_from_bytes", stuck_check)

    async def scenario() -> bool:
        task = asyncio.create_task(service.run())
        await ticked(service, task, 10)
        loading = asyncio.create_task(
            request(service.config.control_socket, load_request(good.read_bytes(), good))
        )
        while not entered.is_set() and not loading.done():
            await asyncio.sleep(0)
        assert entered.is_set(), "the load never reached the check"
        service.stop()
        await task
        loading.cancel()
        return release.is_set()

    try:
        released_early = asyncio.run(scenario())
    finally:
        release.set()
    assert not released_early  # the daemon stopped while the check was still stuck
    assert (service.config.state_dir / "state.json").is_file()  # a clean shutdown saved state


def test_a_second_load_during_a_check_is_refused(tmp_path, monkeypatch):
    """One check at a time: a load arriving while another is checked is refused, not queued."""
    _, good = bad_and_good_models(tmp_path)
    service = daemon(tmp_path)
    release, entered = threading.Event(), threading.Event()
    check = modelload.slot_from_bytes

    def held_check(*args: Any) -> Any:
        entered.set()
        release.wait(GIVE_UP_S)
        return check(*args)

    monkeypatch.setattr(modelload, "slot_from_bytes", held_check)
    replies = {}

    async def scenario() -> None:
        task = asyncio.create_task(service.run())
        await ticked(service, task, 10)
        socket, message = service.config.control_socket, load_request(good.read_bytes(), good)
        first = asyncio.create_task(request(socket, message, timeout_s=GIVE_UP_S))
        while not entered.is_set() and not first.done():
            await asyncio.sleep(0)
        replies["second"] = await request(socket, message)
        release.set()
        replies["first"] = await first
        service.stop()
        await task

    asyncio.run(scenario())
    assert not replies["second"]["ok"] and "still being checked" in replies["second"]["error"]
    assert replies["first"]["ok"]


def test_the_daemon_never_reads_a_path_a_client_names(tmp_path):
    """A load naming a file (a 0600 secret) is refused without opening it; the reply quotes nothing of it."""
    secret = tmp_path / "secret.yaml"
    secret.write_text("schema: SECRET-LINE-hunter2\n")
    secret.chmod(0o600)
    service = daemon(tmp_path)
    replies = {}

    async def scenario() -> None:
        task = asyncio.create_task(service.run())
        await ticked(service, task, 3)
        socket = service.config.control_socket
        replies["path"] = await request(socket, {"cmd": "load", "path": str(secret)})
        replies["shadow"] = await request(socket, {"cmd": "load", "path": "/etc/shadow"})
        service.stop()
        await task

    asyncio.run(scenario())
    for reply in replies.values():
        assert not reply["ok"] and "does not read files named by a client" in reply["error"]
        assert "SECRET" not in reply["error"] and "root" not in reply["error"]


def test_load_is_refused_to_a_peer_outside_load_access_while_status_is_answered(tmp_path):
    """With `load_access` naming another user, this client's load is refused and nothing installed; status works."""
    _, good = bad_and_good_models(tmp_path)
    service = daemon(tmp_path, {"load_access": {"users": [os.getuid() + 12345]}})
    replies = {}

    async def scenario() -> None:
        task = asyncio.create_task(service.run())
        await ticked(service, task, 3)
        socket = service.config.control_socket
        replies["load"] = await request(socket, load_request(good.read_bytes(), good))
        replies["status"] = await request(socket, {"cmd": "status"})
        service.stop()
        await task

    asyncio.run(scenario())
    assert not replies["load"]["ok"] and replies["load"]["error"].startswith(
        "permission denied: 'load'"
    )
    assert replies["status"]["ok"] and replies["status"]["model"]["name"] == "example-gated-arx-y"
    assert not (service.config.state_dir / "models").exists()


def test_an_unknown_user_in_load_access_is_a_config_error(tmp_path):
    """`load_access.users` naming no such user stops check-config, naming the place."""
    with pytest.raises(ConfigFileError, match=r"line \d+ \(load_access\): no such user or group"):
        write_config(tmp_path, {"load_access": {"users": ["no-such-user-compd"]}})


def test_load_refuses_what_model_check_refuses(tmp_path: Path) -> None:
    """A model the guard rails flag (an 8-year sub-model of -1.1e5 um/K) is never accepted by the daemon."""
    from compd.errors import ModelFileError
    from tests.test_modelfile import IMPLAUSIBLE

    config = write_config(tmp_path)
    with pytest.raises(ModelFileError, match="implausible for its own calibration data"):
        modelload.slot_from_bytes(config, IMPLAUSIBLE.encode(), "eight-years.yaml", 0.0)


def test_loading_the_running_model_makes_it_the_one_the_next_start_picks(tmp_path):
    """Another model installed behind the daemon's back is replaced by the running one when that is loaded again."""
    _, good = bad_and_good_models(tmp_path)
    service = daemon(tmp_path)
    config = service.config
    replies = {}

    async def scenario() -> None:
        task = asyncio.create_task(service.run())
        await ticked(service, task, 3)
        # What an old `compd model load` did when it could not reach this daemon.
        install_model_bytes(config.state_dir, good.read_bytes())
        running = Path(config.model_path).read_bytes()
        replies["load"] = await request(config.control_socket, load_request(running, "again"))
        service.stop()
        await task

    asyncio.run(scenario())
    assert replies["load"]["ok"] and replies["load"]["already_running"]
    next_start, _ = startup_slots(config, 0.0)
    assert next_start is not None and next_start.compiled.name == "example-gated-arx-y"
