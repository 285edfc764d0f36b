"""The ``compd`` command line.

Each sub-command lives in one module of this package that exposes
``register(commands)``: it adds its parser and sets ``handler``, a function
that calls the library and renders the result. Errors from bad input end the
command with exit status 2 and a one-paragraph message naming the file, the
place and the fix.

The command line parses first and imports what the chosen command needs
(as git and systemctl do): :data:`COMMANDS` names each command's module and
one-line help, so ``compd --help`` imports no command module and ``compd
status`` only its own. :func:`build_parser` with no argument builds every
command's full parser (for tests and generated help).
"""

from __future__ import annotations

import argparse
import importlib
import os
import signal
import sys
from collections.abc import Sequence
from typing import Any

from compd import __version__
from compd.cli.args import EXIT_INPUT_ERROR
from compd.errors import CompdError
from compd.schemas import CONFIG_SCHEMA, MODEL_SCHEMA

#: What ``compd --version`` prints: compd's version and the file formats it reads and writes.
VERSION = f"compd {__version__}\nmodel files: {MODEL_SCHEMA}\nconfig files: {CONFIG_SCHEMA}"

#: Every command, in the order ``compd --help`` lists them: the module that
#: registers it and its one-line help (checked against the module by the tests).
COMMANDS: dict[str, tuple[str, str]] = {
    "demo": ("compd.cli.demo", "compare the bundled example models with bundled example data"),
    "model": (
        "compd.cli.model",
        "model files: check one, load one into the running daemon, roll one out",
    ),
    "fleet": (
        "compd.cli.fleet",
        "the machines on the fleet's MQTT broker: model, online or offline, last seen",
    ),
    "rollout": (
        "compd.cli.model",
        "check a model file, send it to many machines through the fleet's MQTT broker",
    ),
    "simulate": ("compd.cli.evaluate", "model output and each sub-model's contribution per sample"),
    "compare": ("compd.cli.evaluate", "model against measurement: fit %%, residue, reduction"),
    "fit": (
        "compd.cli.fit",
        "identify TFs (by default a lag bank; ARX, OE or MLR on request) from calibration "
        "data and write a model file",
    ),
    "diagnose": (
        "compd.cli.diagnose",
        "which logged signal (physical effect) explains the model's residue",
    ),
    "extend": (
        "compd.cli.extend",
        "identify a sub-model from an effect's signal to the residue and add it (Horejs 2015, sect. 4.3)",
    ),
    "residual": (
        "compd.cli.residual",
        "stack a random forest on a model's residue against the smoothed door signal "
        "(Swiss-lathe paper) and show the residue before and after",
    ),
    "report": (
        "compd.cli.report",
        "one HTML file: measured vs simulated, residue, failing windows, contributions, "
        "candidates, conditions",
    ),
    "record": (
        "compd.cli.record",
        "record a config's signals (a calibration run) into files compd fit reads",
    ),
    "run": ("compd.cli.service", "the compensation service: read, model, limit, write at 1 Hz"),
    "check-config": (
        "compd.cli.service",
        "validate a daemon config and its model exactly as 'compd run' does",
    ),
    "status": ("compd.cli.service", "the running daemon's model, inputs, offsets, counters"),
    "sensor": ("compd.cli.sensor", "a person vouches for a sensor the daemon stands in for"),
    "read": ("compd.cli.read", "a config's live values, raw and decoded, without the service"),
    "probe": ("compd.cli.read", "read (or, confirmed, write) addresses of a driver, no config"),
    "simulate-machine": (
        "compd.cli.simulate",
        "serve the simulated machine of a config's 'simulation' section, for a compd elsewhere",
    ),
    "twin": ("compd.cli.twin", "generate a run of the simulated milling centre as a data file"),
    "update": (
        "compd.cli.update",
        "re-optimise the model's named gains (g1, g2, ...) on sparse probe measurements (Post-process 2024)",
    ),
    "help": (
        "compd.cli.helpdoc",
        "a command's full help, a topic (config, model-file, units, status-word, exit-codes, "
        "references) or the man page",
    ),
    "completion": ("compd.cli.helpdoc", "the shell completion script (bash, zsh, tcsh, fish)"),
}


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if _command(argv) == "run":
        # SIGHUP's default action ends a process, and logrotate or an operator may send one while
        # the daemon starts: ignored from here, before the daemon's imports (a second or more),
        # until the event loop takes it as a reload (compd.cli.daemon.install_signal_handlers).
        signal.signal(signal.SIGHUP, signal.SIG_IGN)
    parser: argparse.ArgumentParser | None = None
    try:
        parser = build_parser(_chosen_module(argv))
        args = parser.parse_args(argv)
        if not hasattr(args, "handler"):
            parser.print_help()
            return EXIT_INPUT_ERROR
        return int(args.handler(args) or 0)
    except CompdError as exc:
        _print_error(str(exc))
        return int(getattr(exc, "exit_status", EXIT_INPUT_ERROR))
    except BrokenPipeError:
        return _reader_went_away()
    except Exception as exc:
        # A daemon-only install (pip install compd) has no modelling toolkit: a command that
        # needs it (or another extra) says how to get it, in one line, instead of a traceback.
        from compd.extras import hint, missing_extra  # only on the way out

        missing = missing_extra(exc)
        if missing is None:
            raise
        _print_error(hint(_command_words(parser, argv), missing))
        return EXIT_INPUT_ERROR


def _print_error(text: str) -> None:
    """``compd: error: TEXT`` on stderr; under systemd, filed at "err" (journalctl -p err)."""
    from compd.cli.journal import journal_stream  # only on the way out: --help stays light

    prefix = "<3>" if journal_stream(sys.stderr, os.environ) else ""
    lines = f"compd: error: {text}".split("\n")
    print("\n".join(prefix + line for line in lines), file=sys.stderr)


def _command_words(parser: argparse.ArgumentParser | None, argv: Sequence[str]) -> str:
    """``compd fit``, ``compd model check``: the command ``argv`` names, as far as ``parser`` knows it."""
    words = [word for word in argv if not word.startswith("-")]
    named: list[str] = []
    while parser is not None and words:
        sub = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        if not sub or words[0] not in sub[0].choices:
            break
        parser = sub[0].choices[words[0]]
        named.append(words.pop(0))
    if named == ["help"] and words[:1] and words[0] in COMMANDS:
        named.append(words[0])  # compd help fit: fit's parser needs the toolkit
    return " ".join(["compd", *(named or words[:1])])


#: A shell's exit status for a command ended by SIGPIPE (128 + 13), as `yes | head` gives.
EXIT_BROKEN_PIPE = 141


def _reader_went_away() -> int:
    """``compd help | head``: the reader closed the pipe; end quietly, as a filter does.

    Python's own recipe: point stdout at /dev/null, so that the interpreter's
    final flush does not raise the same error again as it exits.
    """
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    return EXIT_BROKEN_PIPE


def build_parser(module: str | None = None) -> argparse.ArgumentParser:
    """The parser with every command in full, or only ``module``'s (the rest named, with help).

    ``module=""`` registers no command module: enough for ``--help`` and ``--version``.
    """
    parser = argparse.ArgumentParser(
        prog="compd", description="Thermal-error compensation for CNC machine tools."
    )
    parser.add_argument(
        "--version", action=_Version, help="compd's version and the file formats it reads"
    )
    commands = parser.add_subparsers(title="commands", metavar="COMMAND")
    registered: set[str] = set()
    unavailable: dict[str, str] = {}  # a command module -> the extra it needs, not installed
    for name, (owner, text) in COMMANDS.items():
        if module is None or owner == module:
            if owner not in registered and owner not in unavailable:
                if (extra := _register(owner, commands, chosen=module is not None)) is None:
                    registered.add(owner)
                else:
                    unavailable[owner] = extra
            if owner in registered:
                continue
        if owner in unavailable:
            # `compd help --man` and `compd completion` in a daemon-only install: named, and why.
            install = f"pip install 'compd[{unavailable[owner]}]'"
            commands.add_parser(
                name, help=f"{text} (needs compd[{unavailable[owner]}])",
                description=f"{text[0].upper()}{text[1:]}. Needs {install}.".replace("%%", "%"),
            )  # fmt: skip
        else:
            commands.add_parser(name, help=text)
    for name, command in commands.choices.items():
        if command.description is None:  # --help opens with what the command does, at least
            line = COMMANDS[name][1].replace("%%", "%")
            command.description = f"{line[0].upper()}{line[1:]}."
    return parser


def _register(owner: str, commands: Any, *, chosen: bool) -> str | None:
    """Register ``owner``'s commands; the extra they import, where it is not installed.

    ``chosen``: the command to run; without the extra, :func:`main` says what to install.
    """
    try:
        importlib.import_module(owner).register(commands)
    except ModuleNotFoundError as exc:
        from compd.extras import missing_extra  # only without an extra

        missing = missing_extra(exc)
        if chosen or missing is None:
            raise
        return missing.extra
    return None


class _Version(argparse.Action):
    """``--version`` printed line by line (argparse's own action refills it into one paragraph)."""

    def __init__(self, option_strings: list[str], dest: str, help: str | None = None) -> None:
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS, help=help)

    def __call__(self, parser: argparse.ArgumentParser, *_: object) -> None:
        print(VERSION)
        parser.exit()


def _chosen_module(argv: Sequence[str]) -> str:
    """The module of the command ``argv`` names (its first word), or "" for none."""
    first = _command(argv)
    return COMMANDS[first][0] if first in COMMANDS else ""


def _command(argv: Sequence[str]) -> str | None:
    """The command ``argv`` names: its first word that is not an option."""
    return next((word for word in argv if not word.startswith("-")), None)
