"""What the commands that run a daemon or a machine share: the ``--config`` they name, the logs."""

from __future__ import annotations

import logging
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import structlog

from compd.cli.journal import JournalPriority, journal_stream
from compd.drivers.library_logs import quiet_library
from compd.files.yamlplace import resolve_path
from compd.service.config.loading import Config, load_config


def config_from_arg(text: str, overrides: Sequence[str] = ()) -> Config:
    """The config ``--config`` names (a path, or ``bundled:NAME``), with ``--set``'s keys, validated."""
    return load_config(resolve_path(text, Path.cwd()), overrides)


def configure_logging(*, json_lines: bool | None = None, level: str = "INFO") -> None:
    """structlog on stderr: JSON lines (journald) by default, human-readable on a terminal.

    Under systemd (stderr is the journal's stream) each line starts with its
    syslog priority (:class:`JournalPriority`), so the journal filters by level.

    stderr, never stdout: stdout carries what a command prints (the live view,
    the summary tables), which a log line would break up or corrupt when piped.
    Standard-library loggers (the control socket, the recorder) go through the same renderer.
    """
    if json_lines is None:
        json_lines = not sys.stderr.isatty()
    shared: list[Any] = [
        structlog.stdlib.add_log_level,
        structlog.stdlib.add_logger_name,
        structlog.processors.TimeStamper(fmt="iso", utc=True),
    ]
    renderer: Any = (
        structlog.processors.JSONRenderer() if json_lines else structlog.dev.ConsoleRenderer()
    )
    structlog.configure(
        processors=[*shared, structlog.stdlib.ProcessorFormatter.wrap_for_formatter],
        logger_factory=structlog.stdlib.LoggerFactory(),
        wrapper_class=structlog.stdlib.BoundLogger,
        # Not cached: compd logs once per fault episode, so the lookup costs nothing, and a
        # cached module-level logger would ignore any later configuration (tests' capture_logs).
        cache_logger_on_first_use=False,
    )
    formatter = structlog.stdlib.ProcessorFormatter(
        foreign_pre_chain=shared,
        processors=[structlog.stdlib.ProcessorFormatter.remove_processors_meta, renderer],
    )
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(
        JournalPriority(formatter) if journal_stream(sys.stderr, os.environ) else formatter
    )
    root = logging.getLogger()
    root.handlers = [handler]
    root.setLevel(level)
    # Capped whichever drivers a config loads (and before any is imported): a library's
    # per-frame debug is never compd's, even at --log-level debug.
    for library in ("pymodbus", "asyncua"):
        quiet_library(library)
