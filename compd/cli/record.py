"""``compd record``: the config's signals, recorded for ``compd fit``, writing nothing to the machine.

Parser only: the work (:mod:`compd.cli.recording`) is imported once the
command is chosen.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from compd.cli.args import clock_options, positive_float


def register(commands: Any) -> None:
    record = commands.add_parser(
        "record",
        help="record a config's signals (a calibration run) into files compd fit reads",
        description="Run the config's signals as a data logger: read and check them every "
        "period and record them, with their health, into CSV files that 'compd fit --data' "
        "reads as they are. Nothing is written to the machine: the config's outputs, model "
        "and status word are left out. A reference displacement (a probe or dial gauge on "
        "a serial line or a Modbus register, unit um) is a signal like any other: its "
        "column is the output 'compd fit --output' names.",
    )
    record.add_argument("--config", required=True, metavar="FILE.yaml", help="path or bundled:NAME")
    length = record.add_mutually_exclusive_group()
    length.add_argument(
        "--hours", type=positive_float, metavar="H", help="record H hours of (scaled) clock time"
    )
    length.add_argument(
        "--duration-s", type=positive_float, metavar="S", help="record S seconds of clock time"
    )
    record.add_argument(
        "--out",
        type=Path,
        default=Path("recording"),
        metavar="DIR",
        help="the directory the files go to, empty or new (default ./recording); one file "
        "per recording up to 1 GB, then the next",
    )
    clock_options(record)
    record.set_defaults(log_level="warning")  # record prints its own progress
    record.set_defaults(handler=_record)


def _record(args: argparse.Namespace) -> int:
    from compd.cli.recording import record_command

    return record_command(args)
