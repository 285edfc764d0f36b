"""Free TCP ports for the servers the tests start, outside the kernel's ephemeral range.

A port found by binding to 0 comes from the ephemeral range, which the kernel
also hands to every outgoing connection: between the probe and the server's
own bind, a client of another test (run in parallel) may take it, and the
server then cannot listen (seen in CI: a simulated PLC on a port a broker
client had just been given). Below that range only explicit binds compete,
and the pick is random, so two parallel tests rarely draw the same port.
"""

from __future__ import annotations

import random
import socket
import subprocess
import time
from pathlib import Path

import pytest

#: Where to pick when the kernel does not say its ephemeral range (Linux's default starts at 32768).
FALLBACK_EPHEMERAL_LOW = 32768
#: The lowest port drawn: above the registered services most hosts run.
LOWEST = 20000


def _ephemeral_low() -> int:
    try:
        low = int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return FALLBACK_EPHEMERAL_LOW
    return low if low > LOWEST + 1000 else FALLBACK_EPHEMERAL_LOW


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nobody listens on now, outside the ephemeral range."""
    high = _ephemeral_low() - 1
    for _ in range(200):
        port = random.randint(LOWEST, high)
        with socket.socket() as probe:
            try:
                probe.bind(("127.0.0.1", port))
            except OSError:
                continue
            return port
    with socket.socket() as probe:  # everything taken: the kernel's pick, as before
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def wait_listening(port: int, process: subprocess.Popen[bytes], bound_s: float = 120.0) -> None:
    """Until something accepts connections on 127.0.0.1:``port`` (the process still running)."""
    deadline = time.monotonic() + bound_s
    while time.monotonic() < deadline and process.poll() is None:
        with socket.socket() as probe:
            if probe.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.1)
    pytest.fail(f"nothing listens on port {port} (exit status {process.poll()})")
