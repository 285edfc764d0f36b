"""The fault soak's config: the bundled simulated machine, every file of the run in one directory.

The soak (:mod:`compd.sim.soak`) and its fault-free reference run
(:mod:`compd.sim.soaksensors`) run the bundled ``simulated.yaml`` as
deployed, with control socket, HTTP server, recorder and state, on a free
port so that several soaks may run side by side.
"""

from __future__ import annotations

import socket
from pathlib import Path

import yaml

from compd.files.yamlplace import resolve_path
from compd.service.config.loading import Config, load_config


def soak_config(directory: Path, *, hours: float, seed: int) -> Config:
    """The bundled simulated machine (Modbus TCP) on a free port, its files under ``directory``.

    ``directory`` should be short (under /tmp): it holds the control socket.
    """
    doc = yaml.safe_load(resolve_path("bundled:simulated.yaml", Path(".")).read_text())
    doc["model"] = str(resolve_path("bundled:simulated_model.yaml", Path(".")))
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        doc["drivers"]["plc"]["settings"]["port"] = s.getsockname()[1]
    doc["state"] = {"directory": str(directory / "state"), "save_every_ticks": 60}
    doc["recorder"] = {"enabled": True, "directory": str(directory / "records")}
    doc["control_socket"] = str(directory / "c.sock")
    doc["http"] = {"port": 0}  # any free port: each service of the soak listens anew
    doc["simulation"] = {"scenario": "production", "hours": hours, "seed": seed}
    path = directory / "compd.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return load_config(path)
