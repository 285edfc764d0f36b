"""The protocol libraries' own logs, quietened: WARNING and up only, each passed on as one compd DEBUG line.

pymodbus logs every failed connect attempt (WARNING) and every unanswered
request with a hex dump of the last frames (ERROR); its server logs each
request it cannot serve with a traceback. asyncua logs every read at INFO
and each dropped session at WARNING. Each failure also reaches compd as an
exception, which the driver link reports once per fault (:mod:`compd.service.loop.links`):
the libraries' copies, once per attempt or per tick, flooded the journal with
dozens of errors and hex dumps per link drop. So a library's logger is set to
WARNING (nothing below is even formatted) and what it still logs stops there
(no propagation to the root handlers) and becomes one DEBUG event of compd,
first line only, for whoever debugs the bus.

Records below WARNING never reach compd's log, whatever level a library's
logger or one of its children is given (``pymodbus.logging`` at DEBUG logs a
hex dump of every frame sent and received, several lines per tick): with
``compd run --log-level debug`` the journal gets compd's own debug, not the
bus traffic. Whoever wants the frames turns on the library's own logging
(``pymodbus.pymodbus_apply_logging_config("DEBUG")``), which writes them itself.
"""

from __future__ import annotations

import logging

import structlog

log = structlog.get_logger("compd.drivers")


class _ToDebug(logging.Handler):
    """Log a library record's first line (no frame dump, no traceback) at DEBUG through compd's log."""

    def __init__(self, library: str) -> None:
        super().__init__(level=logging.WARNING)  # below: frame dumps, a line per read
        self.library = library

    def emit(self, record: logging.LogRecord) -> None:
        first_line = record.getMessage().split("\n", 1)[0]
        log.debug(
            self.library, level=record.levelname.lower(), logger=record.name, message=first_line
        )


def quiet_library(name: str) -> None:
    """``name`` and its child loggers at WARNING (unless set on purpose), passed on at DEBUG; idempotent.

    Whatever the loggers' levels, only records at WARNING and up are passed on.
    """
    logger = logging.getLogger(name)
    if logger.level == logging.NOTSET:  # a level set on purpose (debugging the bus) stays
        logger.setLevel(logging.WARNING)
    if not any(isinstance(h, _ToDebug) for h in logger.handlers):
        logger.addHandler(_ToDebug(name))
        logger.propagate = False
