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


def simulated_and_real(directory: Path, source: Path) -> tuple[Path, Path]:
    """Checkout ``source``'s bundled simulated config on a free port, with its state, recorder and
    control socket in ``directory``; and the same without its ``simulation`` (a real-machine
    config: its PLC served by ``compd simulate-machine`` in another process)."""
    doc = yaml.safe_load((source / "config" / "simulated.yaml").read_text())
    doc["model"] = str(source / "config" / "simulated_model.yaml")
    doc["drivers"]["plc"]["settings"]["port"] = free_port()
    doc["drivers"]["plc"]["timeout_s"] = 10.0  # hang guards on a busy host
    doc["drivers"]["plc"]["settings"]["request_timeout_s"] = 5.0
    doc["state"] = {"directory": str(directory / "state")}
    doc["recorder"] = {"enabled": True, "directory": str(directory / "records")}
    doc["control_socket"] = str(directory / "sim.sock")
    simulated = directory / "simulated.yaml"
    simulated.write_text(yaml.safe_dump(doc))
    del doc["simulation"]
    doc["control_socket"] = str(directory / "real.sock")
    real = directory / "real.yaml"
    real.write_text(yaml.safe_dump(doc))
    return simulated, real
