"""``compd read`` and ``compd probe``: live values without the service, for commissioning.

``read`` reads a config's points through the drivers the daemon would
build, and shows each one as the device gave it (registers, image bytes, a
node's variant, a reply field), decoded as the daemon decodes it, with its
unit and the verdict of its checks. ``probe`` reads one or more addresses of
a driver type before any config exists (like ``mbpoll`` or LinuxCNC's
``halmeter``) and writes one only with ``--write VALUE`` and a confirmation.

Parsers only: the work is :mod:`compd.cli.livepoints` (what is read, and
how) and :mod:`compd.cli.liveview` (the table, the watch loop, the write).
"""

from __future__ import annotations

import argparse
from typing import Any

from compd.cli.args import positive_float


def _count(text: str) -> int:
    """``--count``: a whole number >= 1."""
    if not text.isdigit() or int(text) < 1:
        raise argparse.ArgumentTypeError(f"must be a whole number >= 1, got {text!r}")
    return int(text)


def _watch_options(parser: argparse.ArgumentParser, default_interval_s: float) -> None:
    parser.add_argument(
        "--watch", action="store_true", help="read again and again, refreshing in place, to Ctrl-C"
    )
    parser.add_argument(
        "--interval-s",
        type=positive_float,
        default=default_interval_s,
        metavar="S",
        help=f"seconds between reads with --watch (default {default_interval_s:g})",
    )
    parser.add_argument(
        "--count",
        type=_count,
        metavar="N",
        help="with --watch: stop after N reads (for scripts and tests)",
    )
    parser.add_argument(
        "--json",
        action="store_true",
        help="one JSON object per read (JSON lines with --watch) instead of the table",
    )


def register(commands: Any) -> None:
    read = commands.add_parser(
        "read",
        help="a config's live values, raw and decoded, without the service",
        description="Read the configured points through the config's drivers, as 'compd run' "
        "would, and show raw value, decoded value, unit and the checks' verdict. Exit status 1 "
        "when a point could not be read or failed its checks.",
    )
    read.add_argument("--config", required=True, metavar="FILE.yaml", help="path or bundled:NAME")
    read.add_argument(
        "names",
        nargs="*",
        metavar="NAME",
        help="signals or output axes to read (default: every signal, the offsets and the "
        "status word where the driver reads them back)",
    )
    _watch_options(read, 1.0)
    read.set_defaults(handler=_read)

    probe = commands.add_parser(
        "probe",
        help="read (or, confirmed, write) addresses of a driver, no config",
        description="Build a driver of TYPE from --set/--settings, read each ADDRESS and show "
        "its raw and decoded value (the address's own type, no scaling). "
        "Example: compd probe modbus --set host=192.168.0.10 --set port=502 holding:100:int32",
    )
    probe.add_argument("type", metavar="TYPE", help="driver type, as a config's drivers.NAME.type")
    probe.add_argument("addresses", nargs="+", metavar="ADDRESS", help="address in TYPE's syntax")
    probe.add_argument(
        "--set",
        action="append",
        default=[],
        dest="pairs",
        metavar="KEY=VALUE",
        help="a driver setting (repeatable; VALUE is read as YAML; a.b=V sets a nested key)",
    )
    probe.add_argument(
        "--settings",
        metavar="FILE.yaml",
        help="the driver's settings as a YAML mapping (as under drivers.NAME.settings); "
        "--set overrides its keys; relative file names in it are relative to FILE's folder",
    )
    probe.add_argument(
        "--timeout-s",
        type=positive_float,
        default=2.0,
        metavar="S",
        help="time allowed to connect, and for each read or write (default 2)",
    )
    probe.add_argument(
        "--write",
        metavar="VALUE",
        help="write VALUE (the raw value of the address's type, no scaling) to the one ADDRESS, "
        "after a confirmation, then read it back",
    )
    probe.add_argument(
        "--yes", action="store_true", help="with --write: do not ask (for scripts; be sure)"
    )
    _watch_options(probe, 1.0)
    probe.set_defaults(handler=_probe)


def _read(args: argparse.Namespace) -> int:
    from compd.cli.liveview import read_command

    return read_command(args)


def _probe(args: argparse.Namespace) -> int:
    from compd.cli.liveview import probe_command

    return probe_command(args)
