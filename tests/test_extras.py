"""A daemon-only install (``pip install compd``): the operations run, the toolkit's commands say how to get it.

The extras' libraries (the toolkit's, asyncua) are made unimportable in a
child interpreter (a meta path finder ahead of every other, as if they were
not installed), and compd runs there as a user would type it.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import time
import tomllib
from collections.abc import Iterator
from importlib import metadata
from pathlib import Path

import pytest
import yaml
from packaging.requirements import Requirement

from compd.cli import COMMANDS
from compd.extras import EXTRAS, Missing, hint, missing_extra
from tests.ports import free_port, wait_listening

ROOT = Path(__file__).parent.parent
PROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]

#: Every module an extra brings.
EXTRA_MODULES = sorted(set().union(*(extra.modules for extra in EXTRAS.values())))
#: ``compd ARGV`` in an interpreter where no extra's module can be imported.
WITHOUT_EXTRAS = (
    "import runpy, sys\n"
    f"BLOCKED = {EXTRA_MODULES!r}\n"
    "class NotInstalled:\n"
    "    def find_spec(self, name, path=None, target=None):\n"
    "        if name.partition('.')[0] in BLOCKED:\n"
    "            raise ModuleNotFoundError(f'No module named {name!r}', name=name)\n"
    "sys.meta_path.insert(0, NotInstalled())\n"
    "sys.argv = ['compd', *sys.argv[1:]]\n"
    "runpy.run_module('compd.cli', run_name='__main__')\n"
)

#: Every command that needs the toolkit, as a user would type it.
TOOLKIT_COMMANDS: dict[str, list[str]] = {
    "fit": ["fit", "--data", "cal.csv", "--output", "disp_z_um", "--out", "m.yaml"],
    "simulate": ["simulate", "bundled:simulated_model.yaml", "cut.csv"],
    "compare": ["compare", "bundled:simulated_model.yaml", "cut.csv"],
    "diagnose": ["diagnose", "bundled:simulated_model.yaml", "cut.csv"],
    "extend": ["extend", "bundled:simulated_model.yaml", "cut.csv", "--effect", "auto"],
    "residual": ["residual", "bundled:simulated_model.yaml", "cut.csv"],
    "report": ["report", "bundled:simulated_model.yaml", "cut.csv"],
    "update": ["update", "bundled:simulated_model.yaml", "probes.csv"],
    "demo": ["demo"],
    "twin": ["twin", "--out", "twin.csv"],
    "simulate-machine": ["simulate-machine", "--config", "bundled:simulated.yaml"],
}
#: The simulated machine runs in ``compd run``'s process: the README's first command needs the toolkit.
SIMULATED_RUN = ["run", "--config", "bundled:simulated.yaml", "--time-scale", "max"]
#: A toolkit command's full help needs its parser, which needs the toolkit.
HELP_FIT = ["help", "fit"]


def without_extras(
    *argv: object, home: Path, timeout_s: float = 120
) -> subprocess.CompletedProcess[str]:
    """``compd ARGV`` where the toolkit is not installed; ``home`` its HOME (state dirs of ``~``)."""
    return subprocess.run(
        [sys.executable, "-c", WITHOUT_EXTRAS, *map(str, argv)],
        capture_output=True, text=True, timeout=timeout_s, cwd=home,
        env={**_env(), "HOME": str(home)},
    )  # fmt: skip


def _env() -> dict[str, str]:
    """This environment, without what would change how compd prints."""
    return {k: v for k, v in os.environ.items() if k not in {"COLUMNS", "NO_COLOR"}}


# --- what the extras are -------------------------------------------------------


def names(texts: list[str]) -> set[str]:
    """The distributions ``texts`` require, compd's own extras left out."""
    required = {Requirement(text.split("#")[0]).name.lower() for text in texts}
    return required - {PROJECT["name"]}


@pytest.mark.parametrize("extra", EXTRAS)
def test_each_extras_modules_are_the_import_names_of_its_distributions(extra: str) -> None:
    """EXTRAS names the public top-level modules of the distributions pyproject's extra lists."""
    distributions = names(PROJECT["optional-dependencies"][extra])
    provided = {
        module
        for module, owners in metadata.packages_distributions().items()
        if not module.startswith("_") and {d.lower() for d in owners} & distributions
    }
    assert provided == EXTRAS[extra].modules


def test_the_base_install_holds_no_extra_and_the_tests_all_of_them() -> None:
    """``pip install compd`` brings no extra's library; ``[toolkit]`` has OPC UA, ``[test]`` the toolkit."""
    extras = PROJECT["optional-dependencies"]
    base = names(PROJECT["dependencies"])
    for extra in EXTRAS:
        assert base.isdisjoint(names(extras[extra])), extra
    assert "compd[opcua]" in extras["toolkit"]
    assert "compd[toolkit]" in extras["test"]


def test_a_missing_extras_module_is_found_through_what_wrapped_it() -> None:
    """The module is named from the error itself, what it was raised from, or an exception group's member."""
    missing = ModuleNotFoundError("No module named 'scipy.signal'", name="scipy.signal")
    wrapped = ImportError("driver type 'simulated' cannot be imported")
    wrapped.__cause__ = missing  # raise wrapped from missing
    assert missing_extra(missing) == Missing("toolkit", "scipy")
    assert missing_extra(wrapped) == Missing("toolkit", "scipy")
    assert missing_extra(ExceptionGroup("tasks", [ValueError(), missing])) == Missing(
        "toolkit", "scipy"
    )
    assert missing_extra(ModuleNotFoundError("x", name="asyncua.ua")) == Missing("opcua", "asyncua")
    assert missing_extra(ModuleNotFoundError("x", name="pymodbus")) is None
    assert missing_extra(ValueError("pandas")) is None
    assert hint("compd fit", Missing("toolkit", "pandas")) == (
        "compd fit needs the modelling toolkit: pip install 'compd[toolkit]' (pandas is not installed)"
    )


# --- without the toolkit -------------------------------------------------------


@pytest.fixture
def home() -> Iterator[Path]:
    """A HOME under /tmp (short enough for control sockets), removed after."""
    directory = Path(tempfile.mkdtemp(prefix="compd-extras-", dir="/tmp"))
    yield directory
    shutil.rmtree(directory, ignore_errors=True)


def test_every_command_is_either_an_operation_or_the_toolkits() -> None:
    """The table below names each command of ``compd --help`` once: the toolkit's, or an operation."""
    assert set(TOOLKIT_COMMANDS).isdisjoint(OPERATIONS)
    assert set(TOOLKIT_COMMANDS) | set(OPERATIONS) == set(COMMANDS)


@pytest.mark.parametrize(
    "argv", [*TOOLKIT_COMMANDS.values(), SIMULATED_RUN, HELP_FIT], ids=lambda a: " ".join(a[:1])
)
def test_a_toolkit_command_without_the_toolkit_says_how_to_get_it(
    argv: list[str], home: Path
) -> None:
    """One line naming the command and ``pip install 'compd[toolkit]'``, exit status 2, no traceback."""
    done = without_extras(*argv, home=home)
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr
    command = " ".join(argv[:2] if argv == HELP_FIT else argv[:1])
    line = (
        f"compd: error: compd {command} needs the modelling toolkit: pip install 'compd[toolkit]' ("
    )
    assert line in done.stderr, done.stderr
    assert done.stderr.rstrip().splitlines()[-1].endswith(" is not installed)"), done.stderr


#: Each operations command, with what shows it is there (its help).
OPERATIONS = {
    "run": ["run", "--help"],
    "check-config": ["check-config", "--help"],
    "status": ["status", "--help"],
    "model": ["model", "load", "--help"],
    "fleet": ["fleet", "list", "--help"],
    "rollout": ["rollout", "--help"],
    "sensor": ["sensor", "trust", "--help"],
    "read": ["read", "--help"],
    "probe": ["probe", "--help"],
    "record": ["record", "--help"],
    "help": ["help", "config"],
    "completion": ["completion", "bash"],
}


@pytest.mark.parametrize("argv", OPERATIONS.values(), ids=" ".join)
def test_the_operations_commands_are_there_without_the_toolkit(argv: list[str], home: Path) -> None:
    """The daemon's commands parse and answer in a daemon-only install."""
    done = without_extras(*argv, home=home)
    assert done.returncode == 0, done.stderr
    assert done.stdout


def test_the_manual_page_names_the_toolkits_commands_and_what_they_need(home: Path) -> None:
    """``compd help --man`` without the toolkit: every command, the toolkit's marked as needing it."""
    done = without_extras("help", "--man", home=home)
    assert done.returncode == 0, done.stderr
    for name in COMMANDS:
        assert name.replace("-", "\\-") in done.stdout  # roff escapes the hyphen
    assert "needs compd[toolkit]" in done.stdout


def test_an_opcua_config_without_asyncua_names_the_extra(home: Path) -> None:
    """A config whose controller speaks OPC UA, in an install without it: the error names ``compd[opcua]``."""
    doc = yaml.safe_load((ROOT / "config" / "simulated.yaml").read_text())
    del doc["simulation"]
    doc["drivers"]["plc"] = {"type": "opcua", "settings": {"url": "opc.tcp://127.0.0.1:4840"}}
    config = home / "compd.yaml"
    config.write_text(yaml.safe_dump(doc))
    done = without_extras("check-config", config, home=home)
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr
    assert "driver type 'opcua' cannot be imported" in done.stderr
    assert "(install it: pip install 'compd[opcua]')" in done.stderr


# --- the daemon without the toolkit, for real ------------------------------------


def test_the_daemon_runs_checks_and_answers_without_the_toolkit(home: Path) -> None:
    """check-config, run and status on a real machine's config (the twin serves it from elsewhere)."""
    doc = yaml.safe_load((ROOT / "config" / "simulated.yaml").read_text())
    # The bundled model as shipped: it carries its difference equations at the loop's period.
    model = ROOT / "config" / "simulated_model.yaml"
    port = free_port()
    doc["drivers"]["plc"]["settings"]["port"] = port
    doc["model"] = str(model)
    doc["state"] = {"directory": str(home / "state")}
    doc["recorder"] = {"enabled": False}
    doc["control_socket"] = str(home / "c.sock")
    machine_config = home / "machine.yaml"
    machine_config.write_text(yaml.safe_dump(doc))
    del doc["simulation"]
    doc["drivers"]["plc"]["timeout_s"] = 10.0  # hang guards on a busy host, as in test_architecture
    doc["drivers"]["plc"]["settings"]["request_timeout_s"] = 5.0
    config = home / "compd.yaml"
    config.write_text(yaml.safe_dump(doc))

    checked = without_extras("check-config", config, home=home)
    assert checked.returncode == 0, checked.stderr
    machine = subprocess.Popen(  # the twin, with the toolkit, as a PLC elsewhere
        [sys.executable, "-m", "compd.cli", "simulate-machine", "--config", str(machine_config)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    try:
        wait_listening(port, machine)
        daemon = subprocess.Popen(
            [sys.executable, "-c", WITHOUT_EXTRAS, "run", "--config", str(config),
             "--duration-s", "300", "--log-format", "json"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=home,
            env={**_env(), "HOME": str(home)},
        )  # fmt: skip
        try:
            status = _status_once_running(config, home, daemon)
        finally:
            daemon.terminate()  # SIGTERM: as systemctl stop, the daemon ends cleanly
            _, err = daemon.communicate(timeout=120)
    finally:
        machine.terminate()
        machine.wait(timeout=30)
    assert daemon.returncode == 0, err
    assert "twin-z" in status


def _status_once_running(config: Path, home: Path, daemon: subprocess.Popen[str]) -> str:
    """``compd status``'s answer, asked until the daemon's socket answers (or the daemon ended)."""
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and daemon.poll() is None:
        done = without_extras("status", "--config", config, home=home)
        if done.returncode == 0:
            return done.stdout
        time.sleep(0.5)
    pytest.fail(f"compd status never answered (daemon exit status {daemon.poll()})")
