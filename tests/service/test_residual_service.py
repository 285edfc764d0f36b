"""The service running a stacked model (Swiss-lathe paper): the door residual per tick, and carried across a restart."""

from __future__ import annotations

import asyncio
import dataclasses
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

from compd.cli import main
from compd.cli.daemon import model_load
from compd.files.data import load_data
from compd.files.modelfile import load_model
from compd.files.modelwriter import model_to_yaml
from compd.files.sidecar import sidecar_path
from compd.model.residual import DoorFeatures
from compd.model.run import simulate
from compd.model.structure import InputSpec, Model, Output, SubModel
from compd.model.transfer import DiscreteTF
from compd.service.control.modelload import load_request, startup_slots
from compd.service.control.socket import request
from compd.service.daemon import Service
from compd.service.loop.clock import VirtualClock
from compd.service.store.state import load_state
from compd.toolkit.residual import fit_residual
from tests.stacked import forest_beside

from .daemon_setup import run, short_socket, simulated_doc, ticked, write_config

CHECKS = {"min": -1, "max": 80, "stale_s": 10, "hold_s": 30}


@pytest.fixture(scope="module")
def setup(tmp_path_factory) -> tuple[Path, Path]:
    """Three hours of twin door data at 1 s and a stacked model on it (one TF plus a door forest)."""
    folder = tmp_path_factory.mktemp("residual_service")
    data_path = folder / "door.csv"
    argv = ["twin", "--scenario", "door", "--hours", "3", "--seed", "7", "--out", str(data_path)]
    assert main(argv) == 0
    data = load_data(data_path)
    tf = DiscreteTF.from_coefficients([0.0, 0.002], [1.0, -0.999], 0)
    sub = SubModel("T_spindle", "spindle", InputSpec("T_spindle_degC"), tf)
    door = data.column("door_open")
    features = DoorFeatures("door_open")
    x, _ = features.record(door, 1.0, features.initial_state(door[0]))
    fit = fit_residual(  # a residue that follows the 600 s smoothed door (cool-down after closing)
        -3.0 * x[:, 1], door, signal="door_open", sample_time_s=1.0, trees=10, max_depth=6
    )
    model = Model("stacked-door", 1.0, (Output("disp_z_um", (sub,), fit.residual),))
    path = folder / "stacked.yaml"
    doc = forest_beside(path, fit.residual)
    units = {"T_spindle_degC": "degC", "door_open": "-"}
    path.write_text(model_to_yaml(model, signals=units, residuals={"disp_z_um": doc}))
    return path, data_path


def config_for(folder: Path, model: Path, data: Path, start_s: float = 0.0, **extra: object):
    """The simulated config reading the twin file, with Z offsets from ``disp_z_um``."""
    changes = {
        **extra,
        "model": str(model),
        "drivers": {"machine": {"settings": {"data": str(data), "start_s": start_s}}},
        "signals": {
            name: {"driver": "machine", "address": name, "unit": unit, "checks": CHECKS}
            for name, unit in (("T_spindle_degC", "degC"), ("door_open", "-"))
        },
        "outputs": {
            "Z": {
                "model_output": "disp_z_um",
                "driver": "machine",
                "address": "comp_z_um",
                "sign": -1,
                "max_offset_um": 50,
                "max_rate_um_per_s": 1.0,
            }
        },
        "state": {"save_every_ticks": 10},
    }
    doc = simulated_doc()
    doc["signals"], doc["outputs"] = {}, {}
    return write_config(folder, changes, doc=doc)


def test_service_output_includes_the_residual_as_simulate_does(setup, tmp_path) -> None:
    """Each tick's output is the TF sum plus the forest on the door features, as simulate gives on the same readings."""
    model, data = setup
    service, records = run(config_for(tmp_path, model, data), 3600.0)
    slot = service.compensator.active
    inputs = np.array([[r.values[s] for s in slot.compiled.signals] for r in records])
    reference = simulate(slot.compiled, inputs, slot.compiled.steady_state(inputs[0]))
    outputs = np.array([r.model_outputs["disp_z_um"] for r in records])
    assert_allclose(outputs, reference.outputs[:, 0], atol=1e-9)
    assert reference.residuals is not None and np.ptp(reference.residuals) > 1.0
    saved = load_state(tmp_path / "state")
    assert saved is not None and saved.model_state.residual.size == 5


def test_restart_resumes_the_door_features(setup, tmp_path) -> None:
    """A daemon restarted from its saved state continues the door features where they were, not from a settled door."""
    model, data = setup
    door = load_data(data).column("door_open")
    change = int(np.flatnonzero(np.diff(door) != 0)[0]) + 1  # the door's first change
    config = config_for(tmp_path, model, data)
    first = Service(config, clock=VirtualClock(), control=False, background_saves=False)
    first.leave_as_killed()  # only the periodic saves
    run(first.config, change + 300.0, service=first)  # killed 5 min into the transition
    saved = load_state(tmp_path / "state")
    assert saved is not None and saved.ticks > change  # saved mid-transition
    config = config_for(tmp_path, model, data, start_s=saved.ticks)
    second, after = run(config, 60.0, clock=VirtualClock(wall0_unix_s=saved.saved_at_unix_s))
    assert second.resumed
    whole = load_data(data)
    signals = np.column_stack([whole.column("T_spindle_degC"), whole.column("door_open")])
    compiled = second.compensator.active.compiled
    reference = simulate(
        compiled, signals[saved.ticks : saved.ticks + len(after)], saved.model_state
    )
    outputs = np.array([r.model_outputs["disp_z_um"] for r in after])
    assert_allclose(outputs, reference.outputs[:, 0], atol=1e-9)
    settled = simulate(compiled, signals[saved.ticks : saved.ticks + len(after)],
                       compiled.steady_state(signals[saved.ticks]))  # fmt: skip
    assert settled.residuals is not None and reference.residuals is not None
    assert np.max(np.abs(settled.residuals - reference.residuals)) > 0.1, "the features resumed"


def plain_beside(stacked: Path, folder: Path) -> Path:
    """``stacked``'s TF alone, as the config's model a stacked one is loaded over."""
    model = load_model(stacked).model
    plain = dataclasses.replace(
        model, name="plain", outputs=(dataclasses.replace(model.outputs[0], residual=None),)
    )
    path = folder / "plain.yaml"
    path.write_text(model_to_yaml(plain, signals={"T_spindle_degC": "degC"}))
    return path


def test_a_stacked_model_loaded_into_a_running_daemon_is_the_next_starts(setup, tmp_path) -> None:
    """compd model load of a stacked model: the daemon switches to it, and the next start runs it too
    (its forest installed beside it), not the config's model with the installed one set aside."""
    stacked, data = setup
    config = config_for(
        tmp_path, plain_beside(stacked, tmp_path), data, control_socket=str(short_socket())
    )
    service = Service(config, clock=VirtualClock(), control=True)

    async def scenario() -> int:
        task = asyncio.create_task(service.run())
        await ticked(service, task, 3)
        code = await model_load(config, stacked)
        service.stop()
        await task
        return code

    assert asyncio.run(scenario()) == 0
    next_start, _ = startup_slots(config, 0.0)
    assert next_start is not None and next_start.compiled.name == "stacked-door"
    assert next_start.model_file.model.outputs[0].residual is not None


def test_a_stacked_model_installed_with_no_daemon_running_starts(setup, tmp_path) -> None:
    """compd model load with no daemon: "it will start with this model" holds for a stacked one."""
    stacked, data = setup
    config = config_for(
        tmp_path, plain_beside(stacked, tmp_path), data, control_socket=str(short_socket())
    )
    assert asyncio.run(model_load(config, stacked)) == 0
    next_start, _ = startup_slots(config, 0.0)
    assert next_start is not None and next_start.compiled.name == "stacked-door"


def test_the_daemon_reads_a_stacked_models_forest_from_the_request_not_the_clients_folder(
    setup, tmp_path
) -> None:
    """A load request without the forest its model names is refused: the daemon does not look beside
    the client's file, it reads what the request carries (compd model load sends it)."""
    stacked, data = setup
    config = config_for(
        tmp_path, plain_beside(stacked, tmp_path), data, control_socket=str(short_socket())
    )
    service = Service(config, clock=VirtualClock(), control=True)
    replies = {}

    async def scenario() -> None:
        task = asyncio.create_task(service.run())
        await ticked(service, task, 3)
        raw = stacked.read_bytes()
        socket = config.control_socket
        replies["bare"] = await request(socket, load_request(raw, stacked), timeout_s=120)
        sidecar = {sidecar_path(stacked).name: sidecar_path(stacked).read_bytes()}
        replies["with"] = await request(socket, load_request(raw, stacked, sidecar), timeout_s=120)
        service.stop()
        await task

    asyncio.run(scenario())
    assert not replies["bare"]["ok"] and "forest was not sent with it" in replies["bare"]["error"]
    looked = (
        config.state_dir / "models" / sidecar_path(stacked).name
    )  # its own folder, not the client's
    assert str(looked) in replies["bare"]["error"]
    assert replies["with"]["ok"], replies["with"]
