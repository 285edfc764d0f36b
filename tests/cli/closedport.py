"""deploy/README.md's Modbus TCP config with its PLC on a closed port: a PLC that never answers."""

from __future__ import annotations

import re
import shutil
import sys
from pathlib import Path
from typing import Any

import yaml

from compd.files.yamlplace import resolve_path
from tests.mosquitto import free_port

GUIDE = Path(__file__).parents[2] / "deploy" / "README.md"
#: Guards against a hang on a busy machine, never a timing the tests rely on (s).
WAIT_S = 120.0
#: ``compd run --config`` as a user types it, in this interpreter.
RUN = [sys.executable, "-m", "compd.cli", "run", "--config"]


def closed_port_config(directory: Path, *, http_port: int | None = None) -> Path:
    """The guide's Modbus TCP config (TwinCAT/CODESYS), its PLC on a port of 127.0.0.1 nobody listens on."""
    blocks = re.findall(r"```yaml\n(.*?)```", GUIDE.read_text(), re.S)
    (block,) = [b for b in blocks if "type: modbus" in b]
    doc: dict[str, Any] = yaml.safe_load(block)
    directory.mkdir(parents=True, exist_ok=True)
    model = directory / "machine.yaml"
    shutil.copy(resolve_path("bundled:example_gated_arx.yaml", Path(".")), model)
    doc["model"] = str(model)
    doc["state"] = {"directory": str(directory / "state")}
    doc["control_socket"] = str(directory / "control.sock")
    doc["drivers"]["plc"]["settings"].update(host="127.0.0.1", port=free_port())
    if http_port is not None:
        doc["http"] = {"listen": "127.0.0.1", "port": http_port}
    path = directory / "compd.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path
