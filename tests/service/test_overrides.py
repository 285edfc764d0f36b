"""``--set KEY=VALUE`` changes a config key for one run, checked as if written in the file; the file stays as it is."""

from __future__ import annotations

import re
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from compd.errors import ConfigFileError
from compd.files.yamlplace import resolve_path
from compd.service.config.loading import load_config
from tests.ports import free_port

BUNDLED = resolve_path("bundled:simulated.yaml", Path("."))


def test_the_quick_starts_plc_port_is_set_from_the_command_line() -> None:
    """The driver's port is the one given; the config keeps the overrides (a reload applies them again)."""
    config = load_config(BUNDLED, ["drivers.plc.settings.port=15021", "simulation.hours=0.5"])
    assert config.driver_settings["plc"].port == 15021  # type: ignore[attr-defined]
    assert config.simulation is not None and config.simulation.hours == 0.5
    assert config.overrides == ("drivers.plc.settings.port=15021", "simulation.hours=0.5")
    assert load_config(BUNDLED).driver_settings["plc"].port == 15020  # type: ignore[attr-defined]


@pytest.mark.parametrize(
    ("override", "said"),
    [
        ("drivers.plc.settings.port=http", "(drivers.plc.settings.port)"),
        ("drivers.plc.settings.prot=15021", "did you mean 'port'?"),
        ("simulation.hours.max=3", "the key above 'max' is not a section"),
        ("drivers.plc.settings.port", "is not KEY=VALUE"),
        ("drivers..port=1", "is not KEY=VALUE"),
        ("simulation.seed=[1", "--set simulation.seed"),
    ],
    ids=["wrong-type", "misspelt", "not-a-section", "no-value", "empty-key", "bad-yaml"],
)
def test_a_wrong_override_is_refused_naming_the_key(override: str, said: str) -> None:
    """A value the key does not take, a misspelt key, no ``=``: refused with the key and the fix."""
    with pytest.raises(ConfigFileError) as raised:
        load_config(BUNDLED, [override])
    assert said in str(raised.value)
    if not raised.value.message.startswith(
        "--set"
    ):  # a file's line is named: say it may be --set's
        assert f"(this run also has --set {override})" in str(raised.value)


def _run_on_port(port: int, state: Path) -> subprocess.CompletedProcess[str]:
    """``compd run`` on the bundled simulated config, its PLC on ``port``, 36 s of machine time."""
    argv = ["run", "--config", "bundled:simulated.yaml", "--time-scale", "max"]
    argv += ["--set", f"drivers.plc.settings.port={port}", "--set", "simulation.hours=0.01"]
    argv += ["--set", f"state.directory={state}", "--log-format", "json"]
    return subprocess.run(
        [sys.executable, "-m", "compd.cli", *argv], capture_output=True, text=True, timeout=300
    )  # fmt: skip


def test_compd_run_on_the_bundled_config_follows_the_port_set(tmp_path: Path) -> None:
    """The simulated PLC listens on the port set and the driver connects there: the run compensates."""
    done = _run_on_port(free_port(), tmp_path / "state")
    assert done.returncode == 0, done.stdout + done.stderr
    assert '"driver connected"' in done.stderr
    assert re.search(r"write failures\W+0\b", done.stdout), done.stdout
    assert (tmp_path / "state" / "state.json").is_file()


def test_a_port_in_use_says_how_to_run_on_another(tmp_path: Path) -> None:
    """The quick start's port taken: the error names the --set that moves the PLC elsewhere."""
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        done = _run_on_port(taken.getsockname()[1], tmp_path / "state")
    assert done.returncode == 2
    assert "--set drivers.plc.settings.port=N" in done.stderr
