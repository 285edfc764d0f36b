"""The ``compd`` command line.

Each sub-command lives in one module of this package that exposes
``register(commands)``: it adds its parser and sets ``handler``, a function
that calls the library and renders the result. Errors from bad input end the
command with exit status 2 and a one-paragraph message naming the file, the
place and the fix.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from compd import __version__
from compd.cli.common import EXIT_INPUT_ERROR
from compd.errors import CompdError

#: Command modules, in the order ``compd --help`` lists them.
COMMAND_MODULES = (
    "compd.cli.demo",
    "compd.cli.evaluate",
    "compd.cli.fit",
    "compd.cli.diagnose",
    "compd.cli.extend",
    "compd.cli.residual",
    "compd.cli.report",
    "compd.cli.service",
    "compd.cli.simulate",
    "compd.cli.twin",
    "compd.cli.update",
)


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not hasattr(args, "handler"):
        parser.print_help()
        return EXIT_INPUT_ERROR
    try:
        return int(args.handler(args) or 0)
    except CompdError as exc:
        print(f"compd: error: {exc}", file=sys.stderr)
        return EXIT_INPUT_ERROR


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="compd", description="Thermal-error compensation for CNC machine tools."
    )
    parser.add_argument("--version", action="version", version=f"compd {__version__}")
    commands = parser.add_subparsers(title="commands", metavar="COMMAND")
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(commands)
    return parser
