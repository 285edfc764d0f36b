"""Control socket: a real asyncio unix server and client speaking JSON lines."""

from __future__ import annotations

import asyncio
import json
import math
import os
import re
import shutil
import signal
import socket
import stat
import tempfile
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from compd.errors import ControlError, ModelFileError
from compd.service.config.admission import Access, Peer
from compd.service.control.socket import (
    MAX_LINE_BYTES,
    TOO_DEEP,
    ControlServer,
    request,
    request_sync,
)


@pytest.fixture
def sock_path() -> Iterator[Path]:
    """A socket path short enough for AF_UNIX (108 bytes), unlike pytest's tmp_path."""
    directory = tempfile.mkdtemp(prefix="compd-", dir="/tmp")
    yield Path(directory) / "control.sock"
    shutil.rmtree(directory)


async def status(message: dict[str, Any]) -> dict[str, Any]:
    return {"state": "compensating", "offsets_um": {"z": -12.5}, "echo": message.get("x")}


async def load(message: dict[str, Any]) -> dict[str, Any]:
    raise ModelFileError(message["path"], "no such file", fix="Check the path")


async def broken(message: dict[str, Any]) -> dict[str, Any]:
    return {"ratio": 1 / message["divisor"]}


async def nan(message: dict[str, Any]) -> dict[str, Any]:
    return {"temperature_degC": math.nan}


async def hang(message: dict[str, Any]) -> dict[str, Any]:
    await asyncio.sleep(3600)
    return {}


HANDLERS = {"status": status, "model.load": load, "broken": broken, "nan": nan, "hang": hang}


def serve(path: Path, scenario) -> Any:
    """Run ``scenario()`` against a started server on ``path``; close the server after."""

    async def main() -> Any:
        async with ControlServer(path, HANDLERS):
            return await scenario()

    return asyncio.run(main())


async def raw_exchange(path: Path, *lines: bytes) -> list[dict[str, Any]]:
    """Send raw lines on one connection and read one reply per line."""
    reader, writer = await asyncio.open_unix_connection(str(path), limit=4 * MAX_LINE_BYTES)
    replies = []
    for line in lines:
        writer.write(line)
        await writer.drain()
        replies.append(json.loads(await reader.readline()))
    writer.close()
    await writer.wait_closed()
    return replies


def test_a_command_is_answered_with_ok_and_its_fields(sock_path):
    """One request line gives one reply line: ok true plus the handler's fields."""
    reply = serve(sock_path, lambda: request(sock_path, {"cmd": "status", "x": 3}))
    assert reply == {"ok": True, "state": "compensating", "offsets_um": {"z": -12.5}, "echo": 3}


def test_bad_requests_are_refused_and_the_connection_goes_on(sock_path):
    """Malformed JSON, a non-object, a missing or unknown command each get ok false; later requests still work."""
    lines = [
        b"{not json\n",
        b"[1, 2]\n",
        b'{"x": 1}\n',
        b'{"cmd": "nope"}\n',
        b'{"cmd": "status"}\n',
    ]
    replies = serve(sock_path, lambda: raw_exchange(sock_path, *lines))
    assert [reply["ok"] for reply in replies] == [False, False, False, False, True]
    assert replies[0]["error"].startswith("malformed JSON request")
    assert "known commands: broken, hang, model.load, nan, status" in replies[3]["error"]


def test_handler_failures_are_answered_not_raised(sock_path):
    """A refusal (CompdError) reads as its message, a bug as an internal error; the server keeps serving."""

    async def scenario():
        refused = await request(sock_path, {"cmd": "model.load", "path": "/x/m.yaml"})
        crashed = await request(sock_path, {"cmd": "broken", "divisor": 0})
        after = await request(sock_path, {"cmd": "status"})
        return refused, crashed, after

    refused, crashed, after = serve(sock_path, scenario)
    assert refused == {"ok": False, "error": "/x/m.yaml: no such file. Check the path"}
    assert not crashed["ok"] and "ZeroDivisionError" in crashed["error"]
    assert after["ok"]


def test_nan_in_a_reply_becomes_null(sock_path):
    """JSON has no NaN: an undefined value is sent as null."""
    reply = serve(sock_path, lambda: request(sock_path, {"cmd": "nan"}))
    assert reply == {"ok": True, "temperature_degC": None}


def test_an_oversized_request_is_refused(sock_path):
    """A line longer than the limit is refused instead of buffered without bound."""
    line = b'{"cmd": "status", "x": "' + b"a" * (MAX_LINE_BYTES + 10) + b'"}\n'
    (reply,) = serve(sock_path, lambda: raw_exchange(sock_path, line))
    assert not reply["ok"] and "longer than" in reply["error"]


def test_a_line_nested_too_deeply_is_refused_and_the_connection_goes_on(sock_path):
    """A request of 2 MiB "[" (deeper than the JSON parser recurses) is refused, naming why; the next is answered."""
    deep = b"[" * (MAX_LINE_BYTES - 1) + b"\n"
    replies = serve(sock_path, lambda: raw_exchange(sock_path, deep, b'{"cmd": "status"}\n'))
    assert replies[0] == {"ok": False, "error": f"malformed JSON request: {TOO_DEEP}"}
    assert replies[1]["ok"]


def test_socket_is_group_accessible_only_and_removed_on_close(sock_path):
    """The socket file is mode 0660 while serving and gone after close."""

    async def scenario():
        return stat.S_IMODE(os.stat(sock_path).st_mode), stat.S_ISSOCK(os.stat(sock_path).st_mode)

    mode, is_socket = serve(sock_path, scenario)
    assert mode == 0o660 and is_socket
    assert not sock_path.exists()


def test_a_stale_socket_is_replaced(sock_path):
    """A socket file left by a crashed daemon (nobody listening) does not stop a new start."""
    dead = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    dead.bind(str(sock_path))
    dead.close()  # the file stays, as after a crash
    assert serve(sock_path, lambda: request(sock_path, {"cmd": "status"}))["ok"]


def test_a_live_daemon_is_not_hijacked(sock_path):
    """Starting a second server on a socket a live server listens on is a ControlError."""

    async def scenario():
        with pytest.raises(ControlError, match="already listening"):
            await ControlServer(sock_path, HANDLERS).start()
        return await request(sock_path, {"cmd": "status"})

    assert serve(sock_path, scenario)["ok"]


def test_a_regular_file_at_the_path_is_left_alone(sock_path):
    """A non-socket file at the socket path is refused, never deleted."""
    sock_path.write_text("important")
    with pytest.raises(ControlError, match="not a socket"):
        serve(sock_path, lambda: asyncio.sleep(0))
    assert sock_path.read_text() == "important"


def test_no_daemon_is_a_clear_control_error(sock_path):
    """A client finding no socket is told compd may not be running, with the path."""
    with pytest.raises(
        ControlError, match=re.escape(f"is compd running? socket {sock_path} not found")
    ):
        request_sync(sock_path, {"cmd": "status"})


def test_a_stale_socket_without_daemon_is_a_clear_control_error(sock_path):
    """A client finding a socket nobody listens on is told so."""
    dead = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    dead.bind(str(sock_path))
    dead.close()
    with pytest.raises(ControlError, match="nothing listens"):
        request_sync(sock_path, {"cmd": "status"})


def test_a_slow_handler_times_the_client_out_but_not_the_server(sock_path):
    """A client waits at most timeout_s; other clients are served meanwhile."""

    async def scenario():
        with pytest.raises(ControlError, match=r"no reply from compd .* within 0\.2 s"):
            await request(sock_path, {"cmd": "hang"}, timeout_s=0.2)
        return await request(sock_path, {"cmd": "status"})

    assert serve(sock_path, scenario)["ok"]


def test_close_ends_idle_connections(sock_path):
    """close() returns promptly even when a client keeps its connection open."""

    async def main():
        server = ControlServer(sock_path, HANDLERS)
        await server.start()
        _, writer = await asyncio.open_unix_connection(str(sock_path))
        await asyncio.sleep(0.05)
        await asyncio.wait_for(server.close(), 60.0)  # a hang guard
        writer.close()

    asyncio.run(main())
    assert not sock_path.exists()


def test_request_sync_talks_to_a_daemon_in_another_thread(sock_path):
    """The command line's blocking request reaches a server running its own event loop."""
    started = threading.Event()
    stop: list[asyncio.Event] = []

    async def daemon():
        async with ControlServer(sock_path, HANDLERS):
            stop.append(asyncio.Event())
            started.set()
            await stop[0].wait()

    loop = asyncio.new_event_loop()
    thread = threading.Thread(target=loop.run_until_complete, args=(daemon(),))
    thread.start()
    try:
        assert started.wait(60.0)  # hang guards, not timings
        assert request_sync(sock_path, {"cmd": "status"}, timeout_s=60.0)["state"] == "compensating"
    finally:
        loop.call_soon_threadsafe(stop[0].set)
        thread.join(5.0)
        loop.close()


def test_idle_clients_are_disconnected(sock_path):
    """A client that sends nothing for idle_timeout_s is disconnected and does not hold a slot."""

    async def main():
        async with ControlServer(sock_path, HANDLERS, idle_timeout_s=0.1):
            reader, writer = await asyncio.open_unix_connection(str(sock_path))
            closed = await asyncio.wait_for(reader.read(), 60.0)  # a hang guard
            writer.close()
            return closed

    assert asyncio.run(main()) == b""


def test_too_many_clients_are_turned_away_politely(sock_path):
    """Beyond max_connections a new client is told the server is busy; freed slots serve again."""

    async def main():
        async with ControlServer(sock_path, HANDLERS, max_connections=2):
            held = [await asyncio.open_unix_connection(str(sock_path)) for _ in range(2)]
            await asyncio.sleep(0.05)  # both accepted
            busy = await request(sock_path, {"cmd": "status"})
            for _, writer in held:
                writer.close()
            await asyncio.sleep(0.05)
            return busy, await request(sock_path, {"cmd": "status"})

    busy, served = asyncio.run(main())
    assert busy == {"ok": False, "error": "busy: 2 clients connected"}
    assert served["ok"]


def test_a_command_with_access_runs_only_for_allowed_peers(sock_path):
    """A command given an Access is refused to a peer whose uid and gid are not listed; other commands stay open."""
    me, other = os.getuid(), os.getuid() + 12345
    replies = {}

    async def scenario() -> None:
        for allowed in (frozenset({other}), frozenset({me})):
            access = {"status": Access(allowed, frozenset({os.getgid() + 12345}))}
            async with ControlServer(sock_path, {**HANDLERS, "open": status}, access=access):
                replies[allowed] = (
                    await request(sock_path, {"cmd": "status"}),
                    await request(sock_path, {"cmd": "open"}),
                )

    asyncio.run(scenario())
    refused, open_ = replies[frozenset({other})]
    assert not refused["ok"] and refused["error"].startswith("permission denied: 'status'")
    assert f"not uid {me}, gid {os.getgid()}" in refused["error"]
    assert open_["ok"]
    assert replies[frozenset({me})][0]["ok"]


def test_the_server_reads_the_peers_credentials(sock_path):
    """``peer_of`` reports the connecting process's pid, uid and gid (SO_PEERCRED)."""
    seen = []

    async def who(message: dict[str, Any]) -> dict[str, Any]:
        return {}

    async def scenario() -> None:
        server = ControlServer(sock_path, {"who": who})
        original = server.answer

        async def answer(line: bytes, peer: Peer | None = None) -> dict[str, Any]:
            seen.append(peer)
            return await original(line, peer)

        server.answer = answer  # type: ignore[method-assign]
        async with server:
            await request(sock_path, {"cmd": "who"})

    asyncio.run(scenario())
    assert seen == [Peer(os.getpid(), os.getuid(), os.getgid())]


def test_one_status_only_user_holds_at_most_max_per_peer_connections(sock_path):
    """A user who may not load holds at most 4 connections; the next is told so, a freed one serves again."""
    me, other = os.getuid(), os.getuid() + 12345
    access = {"model.load": Access(frozenset({other}))}

    async def main():
        async with ControlServer(sock_path, HANDLERS, access=access):
            held = [await asyncio.open_unix_connection(str(sock_path)) for _ in range(4)]
            over = await request(sock_path, {"cmd": "status"})
            reader, writer = held.pop()
            writer.write_eof()
            assert await reader.read() == b""  # the server has ended it and freed its slot
            return over, await request(sock_path, {"cmd": "status"})

    over, served = asyncio.run(main())
    assert over == {
        "ok": False,
        "error": f"busy: uid {me} already has 4 connections, the most one user may hold; "
        "close one first",
    }
    assert served["ok"]


def hold_connections_as(uid: int, path: Path, count: int) -> tuple[int, int]:
    """A child process running as ``uid`` that connects ``count`` times to ``path`` and holds on.

    Returns its pid (to kill) and a pipe it writes one byte to once every
    connect() has returned.
    """
    ready_r, ready_w = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: plain sockets only, then _exit
        try:
            os.setgid(uid)
            os.setuid(uid)
            held = []
            for _ in range(count):
                client = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
                client.connect(str(path))
                held.append(client)
            os.write(ready_w, b"x")
            signal.pause()
        finally:
            os._exit(0)
    os.close(ready_w)
    return pid, ready_r


@pytest.mark.skipif(os.geteuid() != 0, reason="connecting as a second user needs root")
def test_a_status_only_user_cannot_lock_out_the_users_who_may_load(sock_path):
    """16 idle connections of a status-only user leave root's status and load answered at once."""
    nobody = 65534
    sock_path.parent.chmod(0o711)
    access = {"model.load": Access(frozenset({0}))}

    async def loaded(message: dict[str, Any]) -> dict[str, Any]:
        return {"loaded": True}

    async def main():
        server = ControlServer(
            sock_path,
            {**HANDLERS, "model.load": loaded},
            mode=0o666,
            access=access,
            idle_timeout_s=3600.0,  # the limits must hold while the idle clients stay
        )
        async with server:
            pid, ready = hold_connections_as(nobody, sock_path, 16)
            try:
                assert await asyncio.to_thread(os.read, ready, 1) == b"x"
                # The socket's queue is first in, first out: the 16 are judged before these.
                return [
                    await request(sock_path, {"cmd": "status"}),
                    await request(sock_path, {"cmd": "model.load"}),
                ]
            finally:
                os.kill(pid, signal.SIGKILL)
                os.waitpid(pid, 0)
                os.close(ready)

    status_reply, load_reply = asyncio.run(main())
    assert status_reply["ok"] and status_reply["state"] == "compensating"
    assert load_reply == {"ok": True, "loaded": True}
