"""Where the daemon's files go: the socket a client finds from two YAML keys is the daemon's own."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml

from compd.service.config.paths import control_socket_of, default_state_dir

from .daemon_setup import merge, simulated_doc


@pytest.mark.parametrize(
    "changes",
    [
        {},
        {"control_socket": "run/compd.sock"},
        {"control_socket": "/tmp/compd-elsewhere.sock", "state": {"directory": "st"}},
        {"state": {"directory": "relative/state"}},
    ],
)
def test_the_socket_from_the_yaml_is_the_one_load_config_finds(
    tmp_path: Path, changes: dict[str, Any], monkeypatch: pytest.MonkeyPatch
) -> None:
    """For a valid config, the two-key reading and the full validation agree on the socket."""
    from compd.service.config.loading import load_config

    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "xdg"))
    doc = merge(simulated_doc(), {"recorder": {"enabled": False}, **changes})
    path = tmp_path / "compd.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    assert control_socket_of(yaml.safe_load(path.read_text()), path.parent) == (
        load_config(path).control_socket
    )


def test_without_a_state_directory_the_socket_is_in_the_xdg_state_home(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """No ``state.directory``: ``$XDG_STATE_HOME/compd/control.sock``; keys of the wrong type count as absent."""
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path))
    assert default_state_dir() == tmp_path / "compd"
    expected = tmp_path / "compd" / "control.sock"
    assert control_socket_of({}, Path("/etc/compd")) == expected
    assert control_socket_of({"state": 3, "control_socket": 4}, Path("/etc/compd")) == expected


def test_the_paths_module_imports_neither_pydantic_nor_numpy() -> None:
    """A quick ``compd status`` can find the socket without the config's schema or the numerics."""
    code = (
        "import sys, compd.service.config.paths; "
        "print(sorted({m.split('.')[0] for m in sys.modules} & {'pydantic', 'numpy', 'scipy'}))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
