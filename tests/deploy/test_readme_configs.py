"""deploy/README.md: its complete configs pass `compd check-config`; its snippets are valid parts of one."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import pytest
import yaml

from compd.files.yamlplace import resolve_path
from compd.service.config.loading import ConfigDoc

from ..clirun import compd

README = Path(__file__).parents[2] / "deploy" / "README.md"
#: The absolute places the guide's configs name, and where the test puts them instead.
PLACES = ("/etc/compd", "/var/lib/compd", "/run/compd")


def yaml_blocks() -> list[str]:
    """The guide's YAML blocks that are compd's: not Prometheus's (which start ``# prometheus.yml``)."""
    blocks = re.findall(r"```yaml\n(.*?)```", README.read_text(), re.S)
    return [b for b in blocks if not b.startswith("# prometheus.yml")]


def complete(block: str) -> bool:
    return block.lstrip().startswith("schema:")


COMPLETE = [b for b in yaml_blocks() if complete(b)]
SNIPPETS = [b for b in yaml_blocks() if not complete(b)]


def test_the_guide_has_a_complete_config_per_controller_family():
    """SINUMERIK, HEIDENHAIN, FANUC gateway, Modbus TCP and OPC UA PLCs: five complete configs at least."""
    assert len(COMPLETE) >= 5
    types = {d["type"] for b in COMPLETE for d in yaml.safe_load(b)["drivers"].values()}
    assert {"opcua", "modbus", "profibus_gateway"} <= types


def relocated(block: str, root: Path) -> str:
    """The block with /etc/compd, /var/lib/compd and /run/compd moved under ``root``."""
    for place in PLACES:
        block = block.replace(place, f"{root}{place}")
    return block


@pytest.mark.parametrize("block", COMPLETE, ids=[f"config{i}" for i in range(len(COMPLETE))])
def test_complete_configs_pass_check_config(block, tmp_path):
    """Each complete config, with its model, certificates and secrets in place, passes `compd check-config`."""
    text = relocated(block, tmp_path)
    doc = yaml.safe_load(text)
    model = Path(doc["model"])
    model.parent.mkdir(parents=True, exist_ok=True)
    shutil.copy(resolve_path("bundled:example_gated_arx.yaml", Path(".")), model)
    for driver in doc["drivers"].values():
        settings = driver["settings"]
        security = settings.get("security")
        files = [settings.get("password_file")]
        if isinstance(security, dict):  # the certificates the guide makes (check-config reads them)
            files += [security[k] for k in ("certificate", "private_key", "server_certificate")]
        for name in filter(None, files):
            Path(name).parent.mkdir(parents=True, exist_ok=True)
            Path(name).write_text("secret\n")
    path = tmp_path / "etc" / "compd" / "compd.yaml"
    path.write_text(text)
    out = compd("check-config", path)
    assert out.startswith("ok: ")


@pytest.mark.parametrize("block", SNIPPETS, ids=[f"snippet{i}" for i in range(len(SNIPPETS))])
def test_snippets_are_valid_parts_of_a_config(block):
    """A partial block (state paths, load_access) validates as keys of a config, merged into the first complete one."""
    part = yaml.safe_load(block)
    assert isinstance(part, dict) and part
    merged = yaml.safe_load(COMPLETE[0]) | part
    ConfigDoc.model_validate(merged)  # keys and types; user names are resolved only on the PC
