"""Where the daemon keeps its files: the state directory, the recordings, the control socket.

Kept apart from the config's schema (:mod:`compd.service.config.docs`) and
cheap to import -- the standard library and :func:`compd.files.yamlplace.resolve_path`,
no pydantic, no numpy -- so that a client that needs only the socket (a quick
``compd status``) can read two keys of the YAML file and find it exactly as
the daemon does.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from compd.files.yamlplace import resolve_path

#: The socket's file name in the state directory, unless ``control_socket`` names another.
SOCKET_NAME = "control.sock"
#: The recorder's directory in the state directory, unless ``recorder.directory`` names another.
RECORDS_NAME = "records"


def default_state_dir() -> Path:
    """``$XDG_STATE_HOME/compd``, else ``~/.local/state/compd``."""
    base = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(base) / "compd"


def state_dir(directory: str | None, base_dir: Path) -> Path:
    """The state directory: ``state.directory`` (relative to the config's folder), else the default."""
    return resolve_path(directory, base_dir) if directory else default_state_dir()


def recorder_dir(directory: str | None, state: Path, base_dir: Path) -> Path:
    """The recorder's directory: ``recorder.directory``, else ``records`` in the state directory."""
    return resolve_path(directory, base_dir) if directory else state / RECORDS_NAME


def control_socket(socket: str | None, state: Path, base_dir: Path) -> Path:
    """The control socket: ``control_socket``, else ``control.sock`` in the state directory.

    A client that reads the YAML itself calls :func:`control_socket_of`.
    """
    return resolve_path(socket, base_dir) if socket else state / SOCKET_NAME


def control_socket_of(data: Mapping[str, Any], base_dir: Path) -> Path:
    """The control socket a config names, from its YAML mapping, nothing else read or checked.

    The same path :func:`compd.service.config.loading.load_config` finds for a valid
    config; keys of the wrong type count as absent (the full validation,
    ``compd check-config``, names them).
    """
    section = data.get("state")
    directory = section.get("directory") if isinstance(section, Mapping) else None
    state = state_dir(_text(directory), base_dir)
    return control_socket(_text(data.get("control_socket")), state, base_dir)


def _text(value: object) -> str | None:
    return value if isinstance(value, str) else None
