"""``compd help`` and ``compd completion``: documentation generated from the parser and the schemas.

``compd help COMMAND`` prints the command's full ``--help``; ``compd help
TOPIC`` a page generated from what compd itself checks (the config and model
file schemas, the status-word bits of the safety stage, the exit codes);
``compd help --man`` the roff manual page of the whole parser. ``compd
completion SHELL`` prints a static completion script of the same parser
(shtab), so a TAB costs the shell nothing: no Python starts.

Parsers only: the pages are built by :mod:`compd.cli.topics` once chosen.
"""

from __future__ import annotations

import argparse
from typing import Any

from compd.cli import COMMANDS
from compd.cli.topicnames import TOPICS

#: Shells ``compd completion`` writes a script for (those shtab supports and compd tests or documents).
SHELLS = ("bash", "zsh", "tcsh", "fish")


def register(commands: Any) -> None:
    topics = "; ".join(f"{name}: {text}" for name, text in TOPICS.items())
    helper = commands.add_parser(
        "help",
        help="a command's full help, a topic (config, model-file, units, status-word, exit-codes, "
        "references) or the man page",
        description=f"Help on a command (its full --help) or a topic. Topics: {topics}.",
    )
    helper.add_argument(
        "topic",
        nargs="?",
        choices=[*COMMANDS, *TOPICS],  # so the completion scripts offer them too
        metavar="COMMAND|TOPIC",
        help="omit for the list",
    )
    helper.add_argument(
        "--man",
        action="store_true",
        help="print the manual page (roff) of every command; pip installs it where man looks "
        "(PREFIX/share/man/man1/compd.1): 'man compd'",
    )
    helper.set_defaults(handler=_help)
    completion = commands.add_parser(
        "completion",
        help="the shell completion script (bash, zsh, tcsh, fish)",
        description="Print a tab-completion script for SHELL, generated from compd's parser. "
        "Install it once, e.g. `compd completion bash > /etc/bash_completion.d/compd` "
        '(zsh: `compd completion zsh > "${fpath[1]}/_compd"`); regenerate it after '
        "upgrading compd.",
    )
    completion.add_argument("shell", choices=SHELLS)
    completion.set_defaults(handler=_completion)


def _help(args: argparse.Namespace) -> int:
    from compd.cli.topics import help_text

    text = help_text(args.topic, man=args.man)
    print(text, end="" if text.endswith("\n") else "\n")
    return 0


def _completion(args: argparse.Namespace) -> int:
    from compd.cli.topics import completion_script

    print(completion_script(args.shell), end="")
    return 0
