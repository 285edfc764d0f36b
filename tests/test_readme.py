"""The README's quick start is what CI runs: its two commands are the two in `.ci/run`."""

import re
from pathlib import Path

ROOT = Path(__file__).parent.parent


def test_quick_start_commands_are_the_ones_ci_runs() -> None:
    """Exactly two commands in the quick start, each run verbatim by `.ci/run`."""
    readme = (ROOT / "README.md").read_text()
    quick = readme[
        readme.index("## Quick start") : readme.index("\n## ", readme.index("## Quick start") + 1)
    ]
    commands = re.findall(r"```sh\n(.*?)\n```", quick, re.S)
    assert len(commands) == 2
    ci = (ROOT / ".ci" / "run").read_text()
    for command in commands:
        assert f"{command} || exit 1" in ci, command
