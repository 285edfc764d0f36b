"""``compd run``, ``compd check-config`` and ``compd status``: the daemon's commands, parsed.

Parsers only: what a command does is imported once it is chosen
(:mod:`compd.cli.daemon`, :mod:`compd.cli.status`), so ``status`` answers
without loading the service, numpy or the simulator.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from compd.cli.args import clock_options, daemon_options, set_option


def register(commands: Any) -> None:
    run = commands.add_parser(
        "run",
        help="the compensation service: read, model, limit, write at 1 Hz",
        description="Run the compensation service of a daemon config: every period read the "
        "signals, run the model, limit each offset (clamp, then slew) and write it to the "
        "machine, until SIGTERM or Ctrl-C (or --duration-s), saving state to resume from. A "
        "config with a 'simulation' section runs against its simulated machine, with a live "
        "view on a terminal. Check a config first with 'compd check-config'.",
    )
    run.add_argument("--config", required=True, metavar="FILE.yaml", help="path or bundled:NAME")
    run.add_argument(
        "--duration-s",
        type=float,
        metavar="S",
        help="stop cleanly after S seconds of (scaled) clock time, saving state",
    )
    run.add_argument(
        "--live-every",
        type=int,
        metavar="N",
        help="print a line every N ticks instead of the live view (default: the live view on "
        "a terminal, nothing otherwise)",
    )
    set_option(run)
    clock_options(run)
    run.set_defaults(handler=_run)

    check = commands.add_parser(
        "check-config",
        help="validate a daemon config and its model exactly as 'compd run' does",
        description="Read a daemon config and the model it names with every check 'compd run' "
        "makes, and print what would run (drivers, signals, axes, and how an address in "
        "another numbering was read); nothing is connected or written. Exit status 0, or 2 "
        "with the file, the place and the fix.",
    )
    check.add_argument("config", metavar="FILE.yaml", help="path or bundled:NAME")
    set_option(check)
    check.set_defaults(handler=_check_config)

    status = commands.add_parser(
        "status",
        help="the running daemon's model, inputs, offsets, counters",
        description="Ask the running daemon, over the control socket its config names, for its "
        "model, inputs, offsets, health and counters, without loading the service.",
    )
    daemon_options(status)
    status.add_argument("--json", action="store_true", help="print the daemon's JSON reply")
    status.set_defaults(handler=_status)


def _run(args: argparse.Namespace) -> int:
    if args.log_format == "json" or (args.log_format == "auto" and not sys.stderr.isatty()):
        structlog_without_rich()
    from compd.cli.daemon import run_command

    return run_command(args)


def _check_config(args: argparse.Namespace) -> int:
    from compd.cli.daemon import check_config_command

    return check_config_command(args)


def _status(args: argparse.Namespace) -> int:
    from compd.cli.status import status_command

    return status_command(args)


#: What ``import structlog`` pulls in when installed and a daemon logging JSON lines never uses.
UNUSED_BY_A_DAEMON = ("rich", "colorama", "greenlet")


def structlog_without_rich() -> None:
    """Import structlog without rich (and pygments), for a daemon that logs JSON lines.

    ``import structlog`` imports ``structlog.dev``, which imports rich's console
    and traceback (with pygments) whenever rich is installed, for the
    ``ConsoleRenderer``'s tracebacks: 5 MB of a daemon's 60 MB that a daemon
    logging JSON lines (journald, any stderr that is no terminal) never uses.
    rich is hidden while structlog is first imported, then shown again: the
    live view on a terminal and every other command still import it.
    ``--log-format console`` and a terminal keep structlog's rich tracebacks.
    colorama (Windows consoles, with ctypes) and greenlet (structlog's deprecated
    greenlet-local context) are hidden the same way: 0.4 MB that a daemon never uses.
    """
    if "structlog" in sys.modules or any(name in sys.modules for name in UNUSED_BY_A_DAEMON):
        return  # imported already: nothing to save, nothing to change
    for name in UNUSED_BY_A_DAEMON:
        sys.modules[name] = None  # type: ignore[assignment]  # import NAME: ImportError
    try:
        import structlog  # noqa: F401  (imported for its side effect: structlog.dev without rich)
    finally:
        for name in UNUSED_BY_A_DAEMON:
            del sys.modules[name]
