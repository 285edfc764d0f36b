"""A command run in a real pseudo-terminal and read through a terminal emulator (pyte), as a person sees it."""

from __future__ import annotations

import errno
import fcntl
import os
import struct
import subprocess
import sys
import termios
from dataclasses import dataclass

import pytest

pyte = pytest.importorskip("pyte", reason="pip install -e '.[test]' (pyte emulates the terminal)")


@dataclass
class Screen:
    """What the terminal showed: every line scrolled off, then the final screen."""

    lines: list[str]
    returncode: int


def run_in_terminal(argv: list[str], *, columns: int = 120, rows: int = 40) -> Screen:
    """Run ``python -m compd.cli *argv`` on a ``columns x rows`` pseudo-terminal (stdout and stderr)."""
    master, slave = os.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", rows, columns, 0, 0))
    env = {k: v for k, v in os.environ.items() if k not in ("COLUMNS", "LINES", "NO_COLOR")}
    env["TERM"] = "xterm-256color"
    process = subprocess.Popen(
        [sys.executable, "-m", "compd.cli", *argv],
        stdin=slave,
        stdout=slave,
        stderr=slave,
        env=env,
        close_fds=True,
    )
    os.close(slave)
    screen = pyte.HistoryScreen(columns, rows, history=100_000)
    stream = pyte.ByteStream(screen)
    while True:
        try:
            data = os.read(master, 65536)
        except OSError as exc:  # EIO: the child closed the terminal
            if exc.errno != errno.EIO:
                raise
            break
        if not data:
            break
        stream.feed(data)
    os.close(master)
    returncode = process.wait(timeout=60)
    scrolled = ["".join(line[x].data for x in range(columns)) for line in screen.history.top]
    return Screen([*scrolled, *screen.display], returncode)
