"""Slow and greedy peers against a real ``compd run``: half-sent HTTP requests under a low open-files limit."""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import resource
import select
import selectors
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

from compd.cli import main
from compd.service.control.peers import EVICT_WAIT_S, Listener, Served
from tests.ports import free_port

from .daemon_setup import short_socket, write_config
from .httprun import http_config, running_compd

#: The daemon's open-files limit (soft and hard): far below systemd's 1024, so a few
#: hundred connections exhaust it, as 1,100 exhaust 1024.
FD_LIMIT = 128
#: Half-sent requests: more than the limit allows descriptors.
ATTACKERS = FD_LIMIT + 72
#: A guard against a hang, not a timing: generous for a busy CI machine.
HANG_S = 120.0
RUN = [sys.executable, "-m", "compd.cli", "run", "--config"]
ESTABLISHED = 1  # TCP_ESTABLISHED, linux/tcp_states.h
HALF_REQUEST = b"GET /status.json HTTP/1.1\r\nHost: compd\r\n"  # no blank line: never complete


def limit_fds() -> None:
    resource.setrlimit(resource.RLIMIT_NOFILE, (FD_LIMIT, FD_LIMIT))


def get(url: str) -> tuple[int, bytes]:
    with urllib.request.urlopen(url, timeout=HANG_S) as response:
        return response.status, response.read()


def wait_for_http(url: str, daemon: subprocess.Popen[str]) -> None:
    deadline = time.monotonic() + HANG_S
    while time.monotonic() < deadline:
        assert daemon.poll() is None, daemon.communicate()[1]
        try:
            get(url)
            return
        except OSError:
            time.sleep(0.1)
    raise AssertionError(f"compd never answered on {url}")


def half_sent_requests(port: int, count: int) -> list[socket.socket]:
    """``count`` connections to ``port``, each with a request whose headers never end."""
    clients = []
    for _ in range(count):
        client = socket.socket()
        client.setblocking(False)
        client.connect_ex(("127.0.0.1", port))
        clients.append(client)
    with selectors.DefaultSelector() as pending:  # poll(): select() stops at fd 1024
        for client in clients:
            pending.register(client, selectors.EVENT_WRITE)
        deadline = time.monotonic() + HANG_S
        while pending.get_map() and time.monotonic() < deadline:
            for key, _ in pending.select(1.0):
                key.fileobj.send(HALF_REQUEST)  # type: ignore[union-attr]
                pending.unregister(key.fileobj)
        assert not pending.get_map(), f"{len(pending.get_map())} never completed the handshake"
    return clients


def wait_closed_by_server(clients: list[socket.socket]) -> None:
    """Until the server has closed every one of ``clients`` (end of stream or reset)."""
    with selectors.DefaultSelector() as open_:
        for client in clients:
            open_.register(client, selectors.EVENT_READ)
        deadline = time.monotonic() + HANG_S
        while open_.get_map() and time.monotonic() < deadline:
            for key, _ in open_.select(1.0):
                try:
                    data = key.fileobj.recv(4096)  # type: ignore[union-attr]
                except ConnectionError:
                    data = b""
                assert data == b"", f"a half-sent request was answered: {data[:100]!r}"
                open_.unregister(key.fileobj)
        assert not open_.get_map(), f"{len(open_.get_map())} slow clients were never disconnected"


def test_half_sent_http_requests_never_take_the_descriptors_the_daemon_needs(
    tmp_path: Path,
) -> None:
    """At an open-files limit of 128, 200 half-sent requests leave status, saves and fds free; each is cut; one log."""
    port = free_port()
    changes = {
        "control_socket": str(short_socket()),
        "http": {"port": port, "idle_timeout_s": 1},
        "state": {"save_every_ticks": 1},
    }
    config = write_config(tmp_path, changes)
    daemon = subprocess.Popen(
        [*RUN, str(config.path), "--time-scale", "1", "--log-format", "json"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=limit_fds,
    )
    url = f"http://127.0.0.1:{port}/"
    try:
        wait_for_http(url + "status.json", daemon)
        clients = half_sent_requests(port, ATTACKERS)
        try:
            # The control socket still has descriptors to answer with.
            assert main(["status", "--config", str(config.path), "--json"]) == 0
            assert len(os.listdir(f"/proc/{daemon.pid}/fd")) < FD_LIMIT - 16
            wait_closed_by_server(clients)
        finally:
            for client in clients:
                client.close()
        status, body = get(url + "status.json")
        assert status == 200 and json.loads(body)["counters"]["ticks"] > 0
    finally:
        daemon.send_signal(signal.SIGTERM)
        _, stderr = daemon.communicate(timeout=HANG_S)
    assert daemon.returncode == 0, stderr
    assert "Too many open files" not in stderr and "Traceback" not in stderr, stderr[-3000:]
    events = [json.loads(line) for line in stderr.splitlines()]
    assert not [e for e in events if e["event"].startswith("cannot save state")]
    capped = [e for e in events if e["event"].startswith("too many connections")]
    assert [e["listener"] for e in capped] == ["http"], capped


def tcp_state(client: socket.socket) -> int:
    """The kernel's TCP state of ``client`` (``tcp_info.tcpi_state``: 1 established, 7 closed)."""
    return client.getsockopt(socket.IPPROTO_TCP, socket.TCP_INFO, 8)[0]


def test_a_client_that_never_reads_its_answers_is_cut(tmp_path: Path) -> None:
    """Pipelined requests whose answers are never read hold their connection only idle_timeout_s, not for ever."""
    with running_compd(http_config(tmp_path, idle_timeout_s=1), hold_at=5) as run:
        port = int(run.url.rsplit(":", 1)[1].rstrip("/"))
        client = socket.socket()
        client.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        client.connect(("127.0.0.1", port))
        client.setblocking(False)
        try:
            requests = b"GET /page.js HTTP/1.1\r\nHost: compd\r\n\r\n" * 2000  # ~16 MB of answers
            with contextlib.suppress(BlockingIOError):
                client.send(requests)
            deadline = time.monotonic() + HANG_S
            while tcp_state(client) == ESTABLISHED and time.monotonic() < deadline:
                time.sleep(0.1)
            assert tcp_state(client) != ESTABLISHED, "the server still holds the connection"
            assert run.service is not None and run.service.http is not None
            assert run.service.http.connections == 0
            assert run.get("/status.json")[0] == 200
        finally:
            client.close()


def silent_connections(port: int, count: int) -> list[socket.socket]:
    """``count`` connections to ``port`` that send nothing."""
    clients = []
    for _ in range(count):
        client = socket.create_connection(("127.0.0.1", port), timeout=HANG_S)
        clients.append(client)
    return clients


def test_metrics_are_served_with_every_connection_held_by_half_open_clients(
    tmp_path: Path,
) -> None:
    """With every slot and more held by clients sending nothing or half a request, /metrics still gets a 200.

    The idle timeout is an hour: only closing the idlest connection for the
    newcomer serves the scrape within the (generous) timeout.
    """
    cap = 4
    config = http_config(tmp_path, max_connections=cap, idle_timeout_s=3600)
    with running_compd(config, hold_at=5) as run:
        assert run.service is not None and run.service.http is not None
        http = run.service.http
        port = int(run.url.rsplit(":", 1)[1].rstrip("/"))
        clients = silent_connections(port, 3 * cap) + half_sent_requests(port, 3 * cap)
        try:
            # The slots are full once one idle client has been closed for another (only a
            # full server evicts); the count itself flickers below the cap as they churn.
            deadline = time.monotonic() + HANG_S
            while http.evicted == 0 and time.monotonic() < deadline:
                time.sleep(0.05)
            assert http.evicted > 0, "the half-open clients never took the slots"
            for _ in range(3):
                with urllib.request.urlopen(run.url + "metrics", timeout=60) as response:
                    assert response.status == 200
                    assert b"compd_ticks_total" in response.read()
            assert http.evicted > 0
        finally:
            for client in clients:
                client.close()


class Hold(asyncio.Protocol):
    """A server protocol that answers nothing: the test marks what it holds busy or not."""

    def __init__(self, transports: list[asyncio.BaseTransport]) -> None:
        self.transports = transports

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transports.append(transport)


def test_a_connection_with_a_request_under_way_is_never_closed_for_another() -> None:
    """One slot, held by a request under way: newcomers wait; once it is idle it is closed for the next."""

    async def scenario() -> None:
        transports: list[asyncio.BaseTransport] = []
        sock = socket.create_server(("127.0.0.1", 0))
        port = sock.getsockname()[1]
        served = Served(lambda: Hold(transports), stall_timeout_s=HANG_S)
        listener = Listener(sock, 1, served, name="test", evict=served.evict_idlest)
        listener.start()
        first, first_writer = await asyncio.open_connection("127.0.0.1", port)
        async with asyncio.timeout(HANG_S):
            while not transports:
                await asyncio.sleep(0.01)
        with served.busy(transports[0]):
            _, second_writer = await asyncio.open_connection("127.0.0.1", port)
            # Long past the eviction age: the busy one is still open, the newcomer queued.
            for _ in range(10):
                await asyncio.sleep(EVICT_WAIT_S)
            assert (len(transports), served.evicted) == (1, 0)
            assert not transports[0].is_closing()
        async with asyncio.timeout(HANG_S):
            assert await first.read() == b""  # closed for the newcomer
            while len(transports) < 2:
                await asyncio.sleep(0.01)
        assert served.evicted == 1 and listener.open == 1
        for writer in (first_writer, second_writer):
            writer.close()
        await listener.close()

    asyncio.run(scenario())


#: A control socket in a process whose descriptors something else used up, then gave back.
STARVED_SERVER = """
import asyncio, concurrent.futures.thread, logging, os, resource, sys
from pathlib import Path
import structlog
from compd.service.control.socket import ControlServer

structlog.configure(wrapper_class=structlog.make_filtering_bound_logger(logging.INFO))
resource.setrlimit(resource.RLIMIT_NOFILE, (128, 128))

async def status(message):
    return {"state": "up"}

async def main():
    async with ControlServer(Path(sys.argv[1]), {"status": status}):
        hog = []
        try:
            while True:
                hog.append(open(os.devnull))
        except OSError:
            pass
        print("full", flush=True)
        await asyncio.to_thread(sys.stdin.readline)
        for file in hog:
            file.close()
        await asyncio.to_thread(sys.stdin.readline)

asyncio.run(main())
"""


class Lines:
    """A process's output read line by line from its pipe's descriptor, with no hidden buffer.

    A text pipe's ``readline`` may take two lines into its buffer at once and
    return one: ``select`` then never reports the second, already read. (The
    starved server logs "cannot accept" right after "full": ``accept()``
    needs a free descriptor before it looks for a client.)
    """

    def __init__(self, process: subprocess.Popen[bytes]) -> None:
        assert process.stdout is not None
        self.fd = process.stdout.fileno()
        self.pending = b""

    def until(self, word: str) -> list[str]:
        """The lines up to the first that holds ``word``."""
        lines: list[str] = []
        while not lines or word not in lines[-1]:
            if b"\n" in self.pending:
                line, self.pending = self.pending.split(b"\n", 1)
                lines.append(line.decode() + "\n")
                continue
            ready, _, _ = select.select([self.fd], [], [], HANG_S)
            assert ready, f"no {word!r} in {lines}"
            chunk = os.read(self.fd, 65536)
            assert chunk, f"the server ended before {word!r}: {lines}"
            self.pending += chunk
        return lines

    def rest(self) -> str:
        """Everything still to come, until the process closes its output."""
        chunks = [self.pending]
        while True:
            ready, _, _ = select.select([self.fd], [], [], HANG_S)
            assert ready, f"the server never ended: {b''.join(chunks)!r}"
            chunk = os.read(self.fd, 65536)
            if not chunk:
                return b"".join(chunks).decode()
            chunks.append(chunk)


def test_running_out_of_descriptors_is_logged_once_and_the_clients_are_served_after() -> None:
    """With every descriptor taken, clients wait in the queue, one line says so; once freed they are answered."""
    path = short_socket()
    server = subprocess.Popen(
        [sys.executable, "-c", STARVED_SERVER, str(path)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
    )
    assert server.stdin is not None
    output = Lines(server)
    clients = []
    try:
        output.until("full")
        for _ in range(3):
            client = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            client.connect(str(path))
            client.sendall(b'{"cmd": "status"}\n')
            clients.append(client)
        starved = output.until("accept")
        server.stdin.write(b"free\n")
        server.stdin.flush()
        for client in clients:
            client.settimeout(HANG_S)
            assert json.loads(client.makefile().readline()) == {"ok": True, "state": "up"}
        server.stdin.write(b"stop\n")
        server.stdin.flush()
        rest = output.rest()
        server.wait(timeout=HANG_S)
    finally:
        for client in clients:
            client.close()
        server.kill()
        server.wait()
    assert "cannot accept a connection" in starved[-1], starved
    everything = "".join(starved) + rest
    assert "Traceback" not in everything, everything
    assert everything.count("cannot accept a connection") == 1, everything
