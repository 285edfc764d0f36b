"""The commands of the simulated machine: `compd run` on a config with `simulation`, `compd simulate-machine`."""

from __future__ import annotations

import socket
import subprocess
import sys
from pathlib import Path

import pytest

from compd.cli import main
from tests.acceptance.conftest import machine_doc, write_config
from tests.clirun import compd


def test_compd_run_on_the_simulated_machine_prints_the_summary(
    calibrated_model: Path, short_dir: Path
) -> None:
    """Off a terminal: live lines every N ticks, then the error table and the fault counts."""
    doc = machine_doc(
        short_dir, calibrated_model, simulation={"scenario": "production", "hours": 1}
    )
    config = write_config(short_dir, doc)
    out = compd("run", "--config", config.path, "--time-scale", "max", "--duration-s", 600,
                "--live-every", 300, "--log-format", "json")  # fmt: skip
    assert "t   0.08 h  Z: offset" in out and "t   0.17 h  Z: offset" in out
    assert "thermal error at the tool centre point" in out and "RMS reduction" in out
    assert "faults injected" in out and "0.17 h simulated" in out


def test_time_scale_max_is_refused_for_a_real_machine(short_dir: Path) -> None:
    """Virtual time only makes sense against a simulated machine."""
    assert main(["run", "--config", "bundled:replay.yaml", "--time-scale", "max"]) == 2


def test_simulate_machine_serves_until_the_scenario_ends(
    calibrated_model: Path, short_dir: Path
) -> None:
    """`compd simulate-machine` alone: the machine runs its scenario and prints the error table."""
    doc = machine_doc(
        short_dir, calibrated_model, simulation={"scenario": "production", "hours": 0.2}
    )
    config = write_config(short_dir, doc)
    command = [sys.executable, "-m", "compd.cli", "simulate-machine", "--config", str(config.path)]
    done = subprocess.run(
        [*command, "--time-scale", "3600"], capture_output=True, text=True, timeout=60
    )
    assert done.returncode == 0, done.stderr
    assert "thermal error at the tool centre point" in done.stdout
    assert "PLC: 0 values written" in done.stdout, "no compd connected"


def test_a_port_in_use_is_a_clear_error_not_a_traceback(
    calibrated_model: Path, short_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Another program on the simulated PLC's port: exit 2, naming the config and the fix."""
    doc = machine_doc(
        short_dir, calibrated_model, simulation={"scenario": "production", "hours": 1}
    )
    config = write_config(short_dir, doc)
    port = doc["drivers"]["plc"]["settings"]["port"]
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", port))
        taken.listen()
        assert main(["run", "--config", str(config.path), "--time-scale", "max"]) == 2
    err = capsys.readouterr().err
    assert str(config.path) in err and f"127.0.0.1:{port}" in err and "another one" in err
