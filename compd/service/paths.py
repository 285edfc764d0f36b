"""Where a daemon keeps its state and its control socket, from its config alone.

Kept apart from the config's schema so that ``compd status`` finds the socket
by reading two keys, without pydantic, numpy or the model (an answer like
``systemctl status``, at once); :func:`compd.service.config.load_config`
resolves the same paths the same way.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from compd.files.yamlplace import resolve_path

#: The control socket's file name in the state directory, unless the config names one.
SOCKET_NAME = "control.sock"


def default_state_dir() -> Path:
    """``$XDG_STATE_HOME/compd``, else ``~/.local/state/compd``."""
    base = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(base) / "compd"


def state_dir_of(directory: str | None, base_dir: Path) -> Path:
    """The config's ``state.directory`` (relative to the config file), else the default."""
    return resolve_path(directory, base_dir) if directory else default_state_dir()


def control_socket_of(socket: str | None, state_dir: Path, base_dir: Path) -> Path:
    """The config's ``control_socket`` (relative to the config file), else in the state dir."""
    return resolve_path(socket, base_dir) if socket else state_dir / SOCKET_NAME


def control_socket_in(data: Mapping[str, Any], base_dir: Path) -> Path | None:
    """The socket a config's parsed YAML names or implies; None if its keys are malformed."""
    state = data.get("state") or {}
    directory = state.get("directory") if isinstance(state, Mapping) else None
    socket = data.get("control_socket")
    if not isinstance(directory, str | None) or not isinstance(socket, str | None):
        return None
    return control_socket_of(socket, state_dir_of(directory, base_dir), base_dir)
