"""``compd run`` on every bundled config imports what the daemon needs: no scipy, no pandas, no toolkit."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml

from compd.files.yamlplace import BUNDLED
from tests.mosquitto import free_port
from tests.test_architecture import NOT_IN_THE_DAEMON, imported_by, loaded

CONFIGS = Path(__file__).parents[1] / "config"
#: Loaded on the way to an error message, never by a daemon that starts.
ONLY_ON_AN_ERROR = ("difflib",)
BUNDLED_CONFIGS = sorted(
    p.name for p in CONFIGS.glob("*.yaml") if "schema: compd.config/1" in p.read_text()
)


def as_a_daemon_runs_it(name: str, directory: Path) -> Path:
    """The bundled config ``name`` as ``compd run`` takes it on an edge PC.

    Its ``simulation`` section goes (the PLC is a separate process, as
    ``compd simulate-machine`` serves it, or a real controller), its state,
    socket and recordings go to ``directory``, and a PLC's port is one nobody
    listens on: the daemon starts, compiles its model, opens its drivers and
    ticks whether or not a controller answers.
    """
    doc: dict[str, Any] = yaml.safe_load((CONFIGS / name).read_text())
    doc.pop("simulation", None)
    if doc.get("model") and not str(doc["model"]).startswith(BUNDLED):
        doc["model"] = f"{BUNDLED}{doc['model']}"
    doc["state"] = {"directory": str(directory / "state")}
    doc["control_socket"] = str(directory / "c.sock")
    if "recorder" in doc:
        doc["recorder"]["directory"] = str(directory / "records")
    for driver in doc["drivers"].values():
        settings = driver.get("settings", {})
        if "port" in settings:
            settings["host"], settings["port"] = "127.0.0.1", free_port()
    path = directory / name
    path.write_text(yaml.safe_dump(doc))
    return path


def test_every_bundled_config_is_checked() -> None:
    """The list below is every daemon config in config/: a new one is checked without a new test."""
    assert {"simulated.yaml", "compd.example.yaml", "replay.yaml", "record.yaml"} <= set(
        BUNDLED_CONFIGS
    )


@pytest.mark.parametrize("name", BUNDLED_CONFIGS)
def test_run_on_a_bundled_config_maps_no_scipy_or_pandas(name: str, tmp_path: Path) -> None:
    """Two seconds of ``compd run``: the model's precompiled equations, the drivers, the loop; numpy alone."""
    config = as_a_daemon_runs_it(name, tmp_path)
    status, modules, out = imported_by(
        "run", "--config", config, "--duration-s", 2, "--log-format", "json"
    )
    # 0: ran; 3: ran, but no controller ever answered (the PLC's port is closed here).
    assert status in (0, 3), out
    assert "compd.service.daemon" in modules, out
    assert loaded(modules, ("scipy", "pandas")) == [], "the daemon steps numpy arrays"
    assert loaded(modules, NOT_IN_THE_DAEMON) == []
    # What only an error in a file needs: the nearest key to a misspelt one.
    assert loaded(modules, ONLY_ON_AN_ERROR) == []
