"""``compd rollout`` beside ``compd fleet``: the roll-out at the top level, and ``--pending`` with nothing pending.

``compd model rollout`` stays the same command. With no desired record on
the broker, ``--pending`` says so (exit status 0) rather than print an empty table.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from compd.cli import build_parser, main
from compd.files.modelwriter import model_to_yaml
from compd.model.structure import InputSpec, Model, Output, SubModel
from compd.model.transfer import DiscreteTF
from compd.toolkit.residual import fit_residual
from tests.mosquitto import WAIT_S, Mosquitto, mosquitto_binary
from tests.stacked import forest_beside

needs_mosquitto = pytest.mark.skipif(
    mosquitto_binary() is None,
    reason="mosquitto is not installed: run .ci/install-system-packages",
)


def test_rollout_is_a_top_level_command_and_a_model_action_alike() -> None:
    """``compd rollout`` and ``compd model rollout`` take the same options into the same handler."""
    parser = build_parser()
    argv = ["model.yaml", "--broker-config", "b.yaml", "--machines", "m1,m2", "--canary", "1"]
    top = parser.parse_args(["rollout", *argv])
    under_model = parser.parse_args(["model", "rollout", *argv])
    assert vars(top) == vars(under_model)
    assert top.handler.__name__ == "_rollout" and top.canary == 1


@pytest.fixture
def empty_broker(broker: Mosquitto, tmp_path: Path) -> list[str]:
    """A broker holding no retained record; the roll-out's broker settings for it."""
    path = tmp_path / "broker.yaml"
    path.write_text(yaml.safe_dump({"host": "127.0.0.1", "port": broker.port}))
    return ["--broker-config", str(path), "--timeout-s", str(WAIT_S)]


@needs_mosquitto
@pytest.mark.parametrize("command", [["rollout"], ["model", "rollout"]])
def test_pending_with_no_desired_record_says_so(
    empty_broker: list[str], capsys: pytest.CaptureFixture[str], command: list[str]
) -> None:
    """No desired record: "no desired models pending", exit status 0, no empty table."""
    assert main([*command, "--pending", *empty_broker]) == 0
    out = capsys.readouterr().out
    assert out.startswith("no desired models pending"), out
    assert "┏" not in out and "machine" not in out.split(":")[0]


@needs_mosquitto
def test_pending_as_json_with_nothing_pending_is_an_empty_list(
    empty_broker: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    """--json with nothing pending: the title and no machines, exit status 0."""
    assert main(["rollout", "--pending", *empty_broker, "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["machines"] == []


def test_a_stacked_model_is_refused_before_anything_is_sent(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A model with a residual forest cannot travel over MQTT: refused with the fix, no broker needed."""
    door = (np.arange(2000) % 200 >= 150).astype(float)
    fit = fit_residual(-3.0 * door, door, signal="door_open", sample_time_s=10.0, trees=5)
    tf = DiscreteTF.from_coefficients([0.0, 0.1], [1.0, -0.9], 0)
    sub = SubModel("T_a", "temperature", InputSpec("T_a_degC"), tf)
    model = tmp_path / "stacked.yaml"
    block = forest_beside(model, fit.residual)
    outputs = (Output("disp_z_um", (sub,), fit.residual),)
    model.write_text(model_to_yaml(Model("stacked", 10.0, outputs), residuals={"disp_z_um": block}))
    broker = tmp_path / "broker.yaml"
    broker.write_text(yaml.safe_dump({"host": "127.0.0.1", "port": 1}))
    argv = ["rollout", str(model), "--broker-config", str(broker), "--machines", "m1"]
    assert main(argv) == 2
    error = " ".join(capsys.readouterr().err.split())
    assert "a stacked model: its residual forest (stacked.residual.npz) does not travel" in error
    assert f"compd model load {model}" in error
