"""pymodbus's own log, quietened: WARNING and up only, each passed on as one compd DEBUG line.

pymodbus logs every failed connect attempt (WARNING) and every unanswered
request with a hex dump of the last frames (ERROR); its server logs each
request it cannot serve with a traceback. Each of these failures also
reaches compd as an exception, which the driver link reports once per fault
(:mod:`compd.links`): pymodbus's copy, once per attempt, flooded the journal
with dozens of errors and hex dumps per link drop. So its logger is set to
WARNING (no frame logging at all below that) and what it still logs becomes
one DEBUG event of compd, first line only, for whoever debugs the bus.
"""

from __future__ import annotations

import logging

import structlog

log = structlog.get_logger("compd.drivers.modbus")

#: pymodbus logs through ``pymodbus.logging``; its parent carries the level.
_PARENT, _SOURCE = "pymodbus", "pymodbus.logging"


class _ToDebug(logging.Filter):
    """Drop the record and log its first line (no frame dump, no traceback) at DEBUG instead."""

    def filter(self, record: logging.LogRecord) -> bool:
        first_line = record.getMessage().split("\n", 1)[0]
        log.debug("pymodbus", level=record.levelname.lower(), message=first_line)
        return False


def quiet_pymodbus() -> None:
    """Set pymodbus's level to WARNING (unless set on purpose) and pass what it logs on at DEBUG; idempotent."""
    parent = logging.getLogger(_PARENT)
    if parent.level == logging.NOTSET:  # a level set on purpose (debugging the bus) stays
        parent.setLevel(logging.WARNING)
    source = logging.getLogger(_SOURCE)
    if not any(isinstance(f, _ToDebug) for f in source.filters):
        source.addFilter(_ToDebug())
