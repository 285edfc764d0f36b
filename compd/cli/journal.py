"""Lines systemd's journal files at their level: the ``<N>`` syslog priority prefix of sd-daemon(3).

Under systemd a service's stderr is a stream into the journal, which files
every line at ``info`` unless the line starts with its priority. compd
prefixes its log lines and its last error line only where stderr is that
stream (``JOURNAL_STREAM``), so a terminal, a pipe or a file never sees a
prefix. Standard library only: the command line's entry point imports it.
"""

from __future__ import annotations

import io
import logging
import os
from collections.abc import Mapping
from typing import TextIO

#: syslog's priorities (sd-daemon(3)), by the standard library's level: ``journalctl -p err``
#: shows CRITICAL and ERROR lines, ``-p warning`` WARNING too.
PRIORITY = {
    logging.CRITICAL: 2,
    logging.ERROR: 3,
    logging.WARNING: 4,
    logging.INFO: 6,
    logging.DEBUG: 7,
}


def journal_stream(stream: TextIO, environ: Mapping[str, str]) -> bool:
    """Whether ``stream`` is systemd's journal: ``JOURNAL_STREAM`` names its device and inode.

    systemd sets the variable for a unit whose output goes to the journal; a
    stream redirected since (a pipe, a file) has another inode and gets no prefix.
    """
    device, _, inode = environ.get("JOURNAL_STREAM", "").partition(":")
    try:
        stat = os.fstat(stream.fileno())
        return (stat.st_dev, stat.st_ino) == (int(device), int(inode))
    except (ValueError, OSError, io.UnsupportedOperation):
        return False


class JournalPriority(logging.Formatter):
    """Each line as ``inner`` renders it, after its syslog priority as ``<3>`` (sd-daemon(3)).

    journald takes the prefix off and files the line at that priority, so
    ``journalctl -p err`` finds compd's faults; without it every line of a
    service's stderr is filed at ``info``.
    """

    def __init__(self, inner: logging.Formatter) -> None:
        super().__init__()
        self.inner = inner

    def format(self, record: logging.LogRecord) -> str:
        priority = PRIORITY.get(record.levelno)
        if priority is None:  # a level between the standard ones: as the one below it
            priority = min((p for lv, p in PRIORITY.items() if lv <= record.levelno), default=7)
        # One journal entry per line: a multi-line message (a traceback) keeps its priority.
        return "\n".join(f"<{priority}>{line}" for line in self.inner.format(record).split("\n"))
