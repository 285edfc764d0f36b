"""``compd --version``, ``help``, ``help --man`` and ``completion``: generated from the parser and schemas."""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tomllib
import typing
from pathlib import Path

import pytest

from compd.cli import COMMANDS, build_parser
from compd.cli.topics import UNIT_SUFFIXES, help_text
from compd.files.modelschema import ModelDoc
from compd.schemas import CONFIG_SCHEMA, MODEL_SCHEMA
from compd.service.config.docs import ConfigDoc
from compd.service.loop.safety import Flag
from compd.toolkit.fitmodel import unit_of

SYSTEM_PACKAGES = ".ci/install-system-packages"


def run(*argv: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "compd.cli", *argv], capture_output=True, text=True, timeout=300
    )  # fmt: skip


def test_version_names_the_file_formats_compd_reads_and_writes() -> None:
    """``--version``: compd's version, then the model-file and config schema versions."""
    done = run("--version")
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert lines[0].startswith("compd ")
    assert f"model files: {MODEL_SCHEMA}" in lines and f"config files: {CONFIG_SCHEMA}" in lines


@pytest.mark.parametrize(("doc", "schema"), [(ModelDoc, MODEL_SCHEMA), (ConfigDoc, CONFIG_SCHEMA)])
def test_the_light_schema_versions_are_those_the_schemas_accept(doc: type, schema: str) -> None:
    """compd.schemas (read by --version without pydantic) agrees with the pydantic schema's literal."""
    annotation = typing.get_type_hints(doc)["schema_"]
    assert typing.get_args(annotation) == (schema,)


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    (action,) = (a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


def test_every_command_registers_the_help_the_table_lists() -> None:
    """COMMANDS (read by ``compd --help`` without importing commands) matches what each module registers."""
    parser = build_parser()
    (action,) = (a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    registered = {choice.dest: choice.help for choice in action._choices_actions}
    assert registered == {name: text for name, (_, text) in COMMANDS.items()}


@pytest.mark.parametrize("command", ["fit", "run", "model"])
def test_help_command_prints_its_full_help(command: str) -> None:
    """``compd help fit`` is ``compd fit --help``, every option included."""
    done = run("help", command)
    assert done.returncode == 0, done.stderr
    assert done.stdout == _subparsers(build_parser())[command].format_help()


def test_help_lists_commands_and_topics() -> None:
    done = run("help")
    assert done.returncode == 0, done.stderr
    for name in [*COMMANDS, "config", "model-file", "units", "status-word", "exit-codes"]:
        assert f"\n  {name} " in done.stdout


def test_an_unknown_topic_is_refused_with_the_list() -> None:
    done = run("help", "configs")
    assert done.returncode == 2
    assert "'configs'" in done.stderr and "model-file" in done.stderr


def test_config_page_lists_every_key_of_the_schema() -> None:
    """Generated from ConfigDoc: every top-level key and every section's keys, with bounds."""
    page = help_text("config")
    for name, field in ConfigDoc.model_fields.items():
        assert f"\n  {field.alias or name}: " in page
    assert "    max_offset_um: float [> 0]" in page
    assert "on_fault: 'ramp' | 'freeze' (= 'ramp')" in page
    assert "compd.example.yaml" in page


def test_model_file_page_lists_every_key_of_the_schema() -> None:
    page = help_text("model-file")
    for name, field in ModelDoc.model_fields.items():
        assert f"\n  {field.alias or name}: " in page
    assert "power_order: 'ascending' | 'descending'" in page


def test_status_word_page_has_every_flag_bit() -> None:
    """Read from the safety stage's constants: every flag at its bit."""
    page = help_text("status-word")
    for flag in Flag:
        bit = flag.value.bit_length() - 1
        assert f"bit {bit:<5} {flag.name.lower().replace('_', ' ')}" in page
    assert "bits 0-1" in page and "bits 8-31" in page and "32768" in page


def test_units_page_names_only_suffixes_compd_reads() -> None:
    """Every suffix on the page is one ``compd fit`` takes a unit from."""
    for suffix in UNIT_SUFFIXES:
        assert unit_of(f"signal{suffix}") != "-", suffix
    assert "  2  refused" in help_text("exit-codes")


def written(path: Path, *argv: str) -> Path:
    """What ``compd ARGV`` printed, written to ``path``."""
    done = run(*argv)
    assert done.returncode == 0, done.stderr
    path.write_text(done.stdout)
    return path


@pytest.fixture(scope="module")
def man_page(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return written(tmp_path_factory.mktemp("man") / "compd.1", "help", "--man")


def test_man_page_renders_without_warnings(man_page: Path) -> None:
    """``man -l`` (man-db and groff) formats it with every warning on and none raised."""
    if shutil.which("man") is None or shutil.which("groff") is None:
        pytest.skip(f"man-db is not installed (see {SYSTEM_PACKAGES})")
    done = subprocess.run(
        ["man", "--warnings=all", "-l", str(man_page)], capture_output=True, text=True,
        timeout=120, env={"MANWIDTH": "100", "MANPAGER": "cat", "PATH": "/usr/bin:/bin"},
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert done.stderr == ""
    for heading in ("SYNOPSIS", "COMMANDS", "EXIT STATUS", "STATUS WORD", "UNITS"):
        assert heading in done.stdout
    assert "--max-offset-um" not in done.stdout  # config keys are not options
    assert "compd fit" in done.stdout and "--data" in done.stdout  # each command's options
    assert "%%" not in done.stdout


@pytest.mark.parametrize("columns", ["40", "120"])
def test_man_page_keeps_help_lines_that_wrap_to_start_with_a_quote(
    tmp_path: Path, columns: str
) -> None:
    """At any terminal width no help line becomes a roff control line: ``'experiment' column`` is kept."""
    if shutil.which("man") is None or shutil.which("groff") is None:
        pytest.skip(f"man-db is not installed (see {SYSTEM_PACKAGES})")
    done = subprocess.run(
        [sys.executable, "-m", "compd.cli", "help", "--man"], capture_output=True, text=True,
        timeout=300, env={**os.environ, "COLUMNS": columns},
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    page = tmp_path / "compd.1"
    page.write_text(done.stdout)
    shown = subprocess.run(
        ["man", "--warnings=all", "-l", str(page)], capture_output=True, text=True,
        timeout=120, env={"MANWIDTH": "100", "MANPAGER": "cat", "PATH": "/usr/bin:/bin"},
    )  # fmt: skip
    assert shown.stderr == ""
    assert "'experiment' column" in " ".join(shown.stdout.split())


ROOT = Path(__file__).parent.parent.parent
#: The page pip installs where man looks (pyproject's data-files).
INSTALLED_PAGE = ROOT / "share" / "man" / "man1" / "compd.1"
REGENERATE = "compd help --man > share/man/man1/compd.1 (COLUMNS unset)"


def _undated(roff: str) -> str:
    """The page without the date in its ``.TH`` line (argparse-manpage writes the day it ran)."""
    return re.sub(r'^(\.TH \S+ "1") "[^"]*"', r"\1", roff, flags=re.M)


def test_the_page_pip_installs_is_the_parsers() -> None:
    """share/man/man1/compd.1, which a wheel installs where man looks, is what ``compd help --man`` prints."""
    env = {key: value for key, value in os.environ.items() if key != "COLUMNS"}
    done = subprocess.run(
        [sys.executable, "-m", "compd.cli", "help", "--man"], capture_output=True, text=True,
        timeout=300, env=env,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert INSTALLED_PAGE.is_file(), f"no {INSTALLED_PAGE}: {REGENERATE}"
    assert _undated(INSTALLED_PAGE.read_text()) == _undated(done.stdout), f"stale: {REGENERATE}"
    setuptools = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert setuptools["data-files"]["share/man/man1"] == ["share/man/man1/compd.1"]


@pytest.mark.parametrize("command", ["run", "check-config", "demo", "status", "simulate-machine"])
def test_the_service_commands_help_says_what_each_does(command: str) -> None:
    """``compd COMMAND --help`` has a paragraph between the usage and the options, not the usage alone."""
    done = run(command, "--help")
    assert done.returncode == 0, done.stderr
    paragraphs = done.stdout.split("\n\n")
    assert paragraphs[1].split()[0] not in ("options:", "positional"), done.stdout
    assert len(paragraphs[1].split()) >= 15


def test_every_command_has_a_description() -> None:
    """Every command's --help opens with what it does (its own paragraph, or its help line)."""
    for name, command in _subparsers(build_parser()).items():
        assert command.description, name


def _bash_completions(script: Path, line: str) -> list[str]:
    """What bash offers for TAB at the end of ``line``, through the function ``complete -p`` names."""
    program = (
        f"source {script}\n"
        "function=$(complete -p compd | sed -E 's/.* -F ([^ ]+) .*/\\1/')\n"
        f"COMP_LINE={line!r}; COMP_POINT=${{#COMP_LINE}}\n"
        'read -ra COMP_WORDS <<< "$COMP_LINE"\n'
        "[[ $COMP_LINE == *' ' ]] && COMP_WORDS+=('')\n"
        "COMP_CWORD=$(( ${#COMP_WORDS[@]} - 1 ))\n"
        "$function\n"
        "printf '%s\\n' \"${COMPREPLY[@]}\"\n"
    )
    done = subprocess.run(["bash", "-c", program], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    return done.stdout.split()


@pytest.fixture(scope="module")
def bash_script(tmp_path_factory: pytest.TempPathFactory) -> Path:
    if shutil.which("bash") is None:
        pytest.skip("no bash")
    return written(tmp_path_factory.mktemp("completion") / "compd.bash", "completion", "bash")


def test_bash_completes_commands(bash_script: Path) -> None:
    """``compd fi<TAB>`` offers fit; ``compd <TAB>`` every command."""
    assert _bash_completions(bash_script, "compd fi") == ["fit"]
    assert set(COMMANDS) <= set(_bash_completions(bash_script, "compd "))
    assert _bash_completions(bash_script, "compd help status-") == ["status-word"]


def test_bash_completes_a_commands_options(bash_script: Path) -> None:
    """``compd fit --d<TAB>`` offers fit's --data (and its other --d options), not another command's."""
    offered = _bash_completions(bash_script, "compd fit --d")
    assert "--data" in offered and "--denoise" in offered
    assert all(option.startswith("--d") for option in offered)
    assert "--config" in _bash_completions(bash_script, "compd run --c")


@pytest.mark.parametrize("shell", ["zsh", "fish"])
def test_other_shells_scripts_parse(shell: str, tmp_path: Path) -> None:
    """The zsh and fish scripts are valid syntax for their shell (``-n``: parse, do not run)."""
    if shutil.which(shell) is None:
        pytest.skip(f"{shell} is not installed (see {SYSTEM_PACKAGES})")
    script = written(tmp_path / f"compd.{shell}", "completion", shell)
    checked = subprocess.run([shell, "-n", str(script)], capture_output=True, text=True)
    assert checked.returncode == 0, checked.stderr


@pytest.mark.parametrize("argv", ["help", "help config", "help --man", "completion bash"])
def test_a_reader_that_stops_early_gets_no_traceback(argv: str) -> None:
    """``compd help | head -c 1`` ends quietly: no BrokenPipeError traceback on stderr."""
    done = subprocess.run(
        ["bash", "-c", f"{sys.executable} -m compd.cli {argv} | head -c 1 >/dev/null; exit ${{PIPESTATUS[0]}}"],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert "Traceback" not in done.stderr and "BrokenPipe" not in done.stderr, done.stderr
    assert done.returncode in (0, 141)


def test_bash_completes_the_twins_scenarios(bash_script: Path) -> None:
    """``compd twin --scenario prod<TAB>`` offers production; ``--scenario <TAB>`` every scenario."""
    assert _bash_completions(bash_script, "compd twin --scenario prod") == ["production"]
    assert {"production", "cutting"} <= set(
        _bash_completions(bash_script, "compd twin --scenario ")
    )
