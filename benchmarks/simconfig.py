"""The bundled simulated machine's config for a benchmark run on virtual time, in a directory of its own."""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

import yaml

from compd.files.yamlplace import resolve_path
from tests.ports import free_port


def bundled_doc(prefix: str) -> tuple[Path, dict[str, Any]]:
    """A fresh directory and ``bundled:simulated.yaml`` as a document: the bundled model, a free
    port, the state and control socket in the directory, no recorder (the caller sets ``simulation``)."""
    directory = Path(tempfile.mkdtemp(prefix=prefix, dir="/tmp"))
    doc = yaml.safe_load(resolve_path("bundled:simulated.yaml", Path(".")).read_text())
    doc["model"] = str(resolve_path("bundled:simulated_model.yaml", Path(".")))
    doc["drivers"]["plc"]["settings"]["port"] = free_port()
    doc["state"] = {"directory": str(directory / "state"), "save_every_ticks": 600}
    doc["recorder"] = {"enabled": False}
    doc["control_socket"] = str(directory / "c.sock")
    return directory, doc
