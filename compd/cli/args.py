"""Argument types and options shared by commands, light enough for every parser.

Nothing here imports numpy, pydantic or a command's library: the parsers
are built before the command is chosen.
"""

from __future__ import annotations

import argparse
from pathlib import Path

#: Exit status of a command that refused its input (a bad file, option or config).
EXIT_INPUT_ERROR = 2
#: ``compd run --duration-s`` ended without its drivers answering once (a PLC off, a wrong address).
EXIT_NOT_CONNECTED = 3

#: The daemon's config when ``--config`` is not given.
DEFAULT_CONFIG = Path("/etc/compd/compd.yaml")


def positive_float(text: str) -> float:
    """An argparse ``type``: a finite number > 0."""
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not 0.0 < value < float("inf"):
        raise argparse.ArgumentTypeError(f"must be a number > 0, got {text!r}")
    return value


def time_scale_arg(text: str) -> float | None:
    """``--time-scale``: a factor > 0, or ``max`` (virtual time, as fast as the I/O allows) as None."""
    return None if text == "max" else positive_float(text)


def daemon_options(parser: argparse.ArgumentParser) -> None:
    """``--config`` of a command that talks to the running daemon."""
    parser.add_argument(
        "--config",
        default=str(DEFAULT_CONFIG),
        metavar="FILE.yaml",
        help=f"the daemon's config (default {DEFAULT_CONFIG}); gives the state dir and socket",
    )


def clock_options(parser: argparse.ArgumentParser) -> None:
    """``--time-scale``, ``--log-format`` and ``--log-level`` of a command that runs the service."""
    parser.add_argument(
        "--time-scale",
        type=time_scale_arg,
        default=1.0,
        metavar="X|max",
        help="run the clock X times faster than real time, or 'max': virtual time, as fast as "
        "the I/O allows (simulated machines only; default 1)",
    )
    parser.add_argument(
        "--log-format",
        choices=("auto", "json", "console"),
        default="auto",
        help="logs on stderr as JSON lines (journald) or human-readable; auto: human-readable "
        "on a terminal",
    )
    parser.add_argument(
        "--log-level",
        choices=("debug", "info", "warning", "error"),
        default="info",
        help="the least severe log records shown (default info); the protocol libraries' "
        "own logs stay capped at WARNING",
    )


def set_option(parser: argparse.ArgumentParser) -> None:
    """``--set KEY=VALUE`` (repeatable): a config key changed for this run, the file left as it is."""
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        dest="overrides",
        metavar="KEY=VALUE",
        help="set a config key for this run (a dotted key, a YAML value; repeatable), e.g. "
        "--set drivers.plc.settings.port=15021: the quick start's PLC on another port (the "
        "simulated machine serves where the driver connects)",
    )


def broker_option(parser: argparse.ArgumentParser) -> None:
    """``--broker-config``: the fleet's MQTT broker (``compd model rollout``, ``compd fleet list``)."""
    parser.add_argument(
        "--broker-config",
        "--telemetry-config",
        type=Path,
        required=True,
        metavar="FILE.yaml",
        help="the broker: a compd config's 'telemetry:' section, or such a section alone "
        "(host, port, tls, username, password_file, topic_prefix)",
    )
