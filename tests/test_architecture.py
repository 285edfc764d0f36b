"""The rooms of ARCHITECTURE.md hold: the import rules, no circles, and commands that load only what they need."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml

from tests.acceptance.conftest import machine_doc
from tests.installed import DRIVER_CONTRACT, console_script, run_installed
from tests.ports import wait_listening

ROOT = Path(__file__).parents[1]
BUNDLED_MODEL = ROOT / "config" / "simulated_model.yaml"
#: What only the modelling toolkit, the report or the twin needs: never the daemon's.
NOT_IN_THE_DAEMON = ("pandas", "sklearn", "plotly", "PyEMD", "matplotlib", "rich.live",
                     "compd.sim", "compd.toolkit", "compd.report")  # fmt: skip
#: What a command's parser must not need: each is imported once the command is chosen.
NOT_IN_A_PARSER = ("numpy", "scipy", "pandas", "pydantic", "structlog", "pymodbus", "asyncua")


def test_each_room_imports_only_the_rooms_below_it() -> None:
    """import-linter checks pyproject.toml's contracts: layers; what the daemon and the driver API may load."""
    lint = str(console_script("lint-imports") or pytest.fail("import-linter is in the test extras"))
    done = run_installed(lint, "--no-cache")  # as a developer runs it: python -m tests.installed
    assert done.returncode == 0, done.stdout + done.stderr
    assert "0 broken" in done.stdout
    # The driver interface's contract: drivers/ is compd.drivers only as installed.
    done = run_installed(lint, "--no-cache", DRIVER_CONTRACT)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "1 kept, 0 broken" in done.stdout


def test_a_plain_lint_imports_in_the_checkout_runs_the_layers() -> None:
    """Without the installed layout (no compd/drivers folder) the layers still check: drivers is optional there."""
    lint = str(console_script("lint-imports") or pytest.fail("import-linter is in the test extras"))
    done = subprocess.run(
        [lint, "--no-cache"], cwd=ROOT, capture_output=True, text=True, timeout=600
    )
    assert done.returncode == 0, done.stdout + done.stderr
    assert "0 broken" in done.stdout


def test_no_module_imports_itself_through_others() -> None:
    """No import circle at run time (annotation-only imports aside): each module builds on finished ones."""
    script = (
        "import graphlib, grimp\n"
        "graph = grimp.build_graph('compd', cache_dir=None, exclude_type_checking_imports=True)\n"
        "edges = {m: graph.find_modules_directly_imported_by(m) for m in graph.modules}\n"
        "try:\n"
        "    graphlib.TopologicalSorter(edges).prepare()\n"
        "except graphlib.CycleError as exc:\n"
        "    print(' -> '.join(exc.args[1])); raise SystemExit(1)\n"
        "assert 'compd.drivers.modbus.driver' in edges, 'the drivers are in the graph'\n"
        "print(len(edges), 'modules')\n"
    )
    done = run_installed(sys.executable, "-c", script)
    assert done.returncode == 0, f"an import circle: {done.stdout}{done.stderr}"


#: Runs ``compd ARGV`` and, at exit, lists every module it imported.
WITH_MODULES = (
    "import atexit, runpy, sys\n"
    "atexit.register(lambda: print('MODULES', *sorted(sys.modules), file=sys.stderr))\n"
    "sys.argv = ['compd', *sys.argv[1:]]\n"
    "runpy.run_module('compd.cli', run_name='__main__')\n"
)


def imported_by(*argv: object) -> tuple[int, set[str], str]:
    """Exit status, every module ``compd ARGV`` imported, and its output."""
    done = subprocess.run(
        [sys.executable, "-c", WITH_MODULES, *map(str, argv)],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    listed = [line for line in done.stderr.splitlines() if line.startswith("MODULES ")]
    assert listed, done.stdout + done.stderr
    return done.returncode, set(listed[-1].split()[1:]), done.stdout + done.stderr


def loaded(modules: set[str], packages: tuple[str, ...]) -> list[str]:
    return sorted(m for m in modules if any(m == p or m.startswith(p + ".") for p in packages))


@pytest.mark.parametrize("argv", [["--help"], ["--version"], []])
def test_help_and_version_import_no_command(argv: list[str]) -> None:
    """``compd --help`` lists every command from a table: no command's module, no library."""
    _, modules, out = imported_by(*argv)
    assert "compd" in out
    assert loaded(modules, NOT_IN_A_PARSER) == []
    assert loaded(modules, ("compd.cli",)) == ["compd.cli", "compd.cli.args"]


def test_status_finds_the_socket_without_loading_the_service(tmp_path: Path) -> None:
    """No daemon: ``compd status`` says so from two keys of the config, like ``systemctl status``."""
    config = tmp_path / "compd.yaml"
    doc = machine_doc(tmp_path, BUNDLED_MODEL, simulation={"scenario": "production"})
    config.write_text(yaml.safe_dump(doc))
    status, modules, out = imported_by("status", "--config", config)
    assert status == 2 and str(tmp_path / "c.sock") in out
    assert loaded(modules, (*NOT_IN_A_PARSER, "compd.service.config.loading", "compd.model")) == []


@pytest.fixture
def short_dir() -> Iterator[Path]:
    directory = Path(shutil.os.path.join("/tmp", f"compd-arch-{os.getpid()}"))  # type: ignore[attr-defined]
    directory.mkdir(exist_ok=True)
    yield directory
    shutil.rmtree(directory, ignore_errors=True)


def test_run_for_a_real_machine_loads_no_toolkit_twin_or_plotting(short_dir: Path) -> None:
    """The daemon against a controller elsewhere (here the twin's own process) imports no modelling stack.

    The bundled model carries its difference equations at the loop's period,
    so it loads no scipy either: compiled, checked and stepped with numpy.
    """
    doc = machine_doc(short_dir, BUNDLED_MODEL, simulation={"scenario": "production", "hours": 1})
    assert doc["period_s"] == 1.0
    machine_config = short_dir / "machine.yaml"
    machine_config.write_text(yaml.safe_dump(doc))
    del doc["simulation"]
    doc["control_socket"] = str(short_dir / "run.sock")
    # Hang guards, not the bundled 0.3/0.5 s: on a busy host the twin's process answers late,
    # and a run whose reads all timed out ends "not connected" (exit 3), not what this checks.
    doc["drivers"]["plc"]["timeout_s"] = 10.0
    doc["drivers"]["plc"]["settings"]["request_timeout_s"] = 5.0
    real_config = short_dir / "compd.yaml"
    real_config.write_text(yaml.safe_dump(doc))
    machine = subprocess.Popen(
        [sys.executable, "-m", "compd.cli", "simulate-machine", "--config", str(machine_config)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    try:
        # The twin's process listens before the daemon starts: a run that never connects fails.
        wait_listening(doc["drivers"]["plc"]["settings"]["port"], machine)
        status, modules, out = imported_by(
            "run", "--config", real_config, "--duration-s", 5, "--log-format", "json"
        )
    finally:
        machine.terminate()
        machine.wait(timeout=30)
    assert status == 0, out
    assert {"compd.service.daemon", "compd.drivers.modbus.driver"} <= modules, loaded(
        modules, ("compd",)
    )
    assert loaded(modules, NOT_IN_THE_DAEMON) == []
    assert loaded(modules, ("asyncua", "can")) == [], "only the drivers the config names"
    # JSON logs and no terminal: structlog's rich tracebacks and the terminal's console unused.
    assert loaded(modules, ("rich", "pygments")) == [], "rich (5 MB) only for a terminal"
    assert loaded(modules, ("colorama", "greenlet")) == [], "a Windows console, greenlet contexts"
    # A model file's precompiled difference equations are compiled, checked and stepped with numpy.
    assert loaded(modules, ("scipy",)) == [], "scipy (~100 MB) only converts TFs, in the toolkit"
    # No 'probes' section: the probe update's numerics (about 1.4 MB resident) stay out.
    probe_numerics = (
        "compd.service.loop.probing",
        "compd.model.probeupdate",
        "compd.files.probestate",
    )
    assert loaded(modules, probe_numerics) == [], (
        "the probe update only where probes are configured"
    )
