"""Shared set-up of the acceptance tests: a model calibrated on the twin, configs of the simulated machine.

Every test runs compd unchanged against the simulated machine over a real
protocol, on virtual time (``compd run --time-scale max``'s clock), in one
process; only the daemon-restart test runs ``compd run`` as a child process.
"""

from __future__ import annotations

import asyncio
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from compd.files.yamlplace import resolve_path
from compd.service.config.loading import Config, load_config
from compd.sim.plc.machine import AxisSummary
from compd.sim.plc.run import SimulationResult, run_simulation
from tests.clirun import compd
from tests.ports import free_port

CALIBRATION_HOURS = 24
CALIBRATION_SAMPLE_S = 10
BASE_INPUTS = "T_spindle_degC,T_headstock_degC,T_column_front_degC,T_ambient_degC"
SIMULATED = resolve_path("bundled:simulated.yaml", Path("."))


@pytest.fixture(scope="session")
def calibrated_model(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``compd fit`` on 24 h of twin calibration data: OE, four temperatures, Z axis; run at 1 or 5 s."""
    folder = tmp_path_factory.mktemp("calibration")
    data = folder / "calibration.csv"
    model = folder / "twin-z.yaml"
    compd(
        "twin", "--scenario", "calibration", "--hours", CALIBRATION_HOURS, "--seed", 2,
        "--sample-time-s", CALIBRATION_SAMPLE_S, "--out", data,
    )  # fmt: skip
    compd(
        "fit", "--data", data, "--output", "disp_z_um", "--inputs", BASE_INPUTS,
        "--method", "oe", "--name", "twin-z", "--out", model,
    )  # fmt: skip
    # fit writes its difference equations at 1 s; some shifts here tick at 5 s, and compd run
    # converts nothing: the period added as a user adds it.
    compd("model", "compile", model, "--period-s", 5)
    return model


@pytest.fixture
def short_dir() -> Iterator[Path]:
    """A directory under /tmp: AF_UNIX socket paths must stay under 108 bytes."""
    directory = Path(tempfile.mkdtemp(prefix="compd-acc-", dir="/tmp"))
    yield directory
    shutil.rmtree(directory, ignore_errors=True)


def machine_doc(
    directory: Path, model: Path, *, simulation: dict[str, Any], **changes: Any
) -> dict[str, Any]:
    """The bundled simulated-machine config on a free port, its files under ``directory``."""
    doc: dict[str, Any] = yaml.safe_load(SIMULATED.read_text())
    doc["model"] = str(model)
    doc["drivers"]["plc"]["settings"]["port"] = free_port()
    doc["state"] = {"directory": str(directory / "state"), "save_every_ticks": 60}
    doc["recorder"] = {"enabled": True, "directory": str(directory / "records")}
    doc["control_socket"] = str(directory / "c.sock")
    doc["simulation"] = simulation
    doc.update(changes)
    return doc


def write_config(directory: Path, doc: dict[str, Any], name: str = "compd.yaml") -> Config:
    path = directory / name
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return load_config(path)


def simulate(config: Config, **kwargs: Any) -> SimulationResult:
    return asyncio.run(run_simulation(config, **kwargs))


def axis(result: SimulationResult, name: str = "Z") -> AxisSummary:
    return next(a for a in result.summary if a.axis == name)


def offset_steps_um(result: SimulationResult, twin_axis: int = 2) -> np.ndarray:
    """The change of the applied offset between successive machine samples, um."""
    steps = np.diff(result.machine.offset_um[: result.machine.k + 1, twin_axis])
    return np.asarray(np.abs(steps))
