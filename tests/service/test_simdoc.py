"""The `simulation:` section is a section like the others: checked as read, documented by `compd help config`."""

from __future__ import annotations

import typing
from pathlib import Path
from typing import Any

import pytest
import yaml
from pydantic import BaseModel

from compd.cli.topics import help_text
from compd.errors import ConfigFileError
from compd.files.yamlplace import resolve_path
from compd.service.config.loading import load_config
from compd.service.config.simdoc import SimFaultDoc, SimulationDoc


def _simulated(tmp_path: Path, **simulation: Any) -> Path:
    """The bundled simulated config with ``simulation`` keys changed, written under ``tmp_path``."""
    bundled = resolve_path("bundled:simulated.yaml", Path("."))
    doc = yaml.safe_load(bundled.read_text())
    doc["model"] = str(bundled.parent / doc["model"])
    doc["simulation"] |= simulation
    path = tmp_path / "simulated.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def _keys(doc: type[BaseModel], prefix: str = "simulation") -> list[tuple[str, str | None]]:
    """Every key of ``doc`` with its description, nested sections included."""
    found = []
    hints = typing.get_type_hints(doc, include_extras=True)
    for name, field in doc.model_fields.items():
        found.append((f"{prefix}.{name}", field.description))
        inner = [a for a in typing.get_args(hints[name]) if isinstance(a, type)]
        for section in [hints[name], *inner]:
            if isinstance(section, type) and issubclass(section, BaseModel):
                found += _keys(section, f"{prefix}.{name}")
    return found


def test_every_simulation_key_has_a_description_the_help_page_shows() -> None:
    """Each key of the section (faults and probe cycles included) is described, and the page shows it."""
    page = help_text("config")
    assert "simulation: section | null" in page
    for key, description in _keys(SimulationDoc):
        assert description, f"{key} has no description"
        assert description.split()[0] in page, key


def test_the_help_page_names_every_fault_kind_and_what_it_does() -> None:
    """``compd help config`` lists the fault kinds (offset and drift among them) with their meaning."""
    page = help_text("config")
    for kind in typing.get_args(SimFaultDoc.model_fields["kind"].annotation):
        assert f"'{kind}'" in page and f"{kind}: " in page
    assert "stop_at_end: bool (= True)" in page and "variant: str (= 'reference')" in page


def test_telemetrys_machine_id_shows_its_default_the_top_level_one() -> None:
    """``telemetry.machine_id`` is not shown as required: it defaults to the top-level ``machine_id``."""
    page = help_text("config")
    assert "    machine_id: str (= the top-level machine_id)" in page


@pytest.mark.parametrize(
    ("simulation", "place", "fix"),
    [
        ({"hour": 3}, "simulation.hour", "did you mean 'hours'?"),
        ({"hours": 0}, "simulation.hours", "Give a larger value"),
        (
            {"faults": [{"kind": "ofset", "signal": "T_spindle_degC", "at_s": 1, "duration_s": 1}]},
            "simulation.faults[0].kind",
            "'offset'",
        ),
        (
            {
                "faults": [
                    {"kind": "offset", "signal": "T_spindle_degC", "at_s": 1, "duration_s": 1}
                ]
            },
            "simulation.faults[0]",
            "needs 'value'",
        ),
        ({"probes": {"every_h": -1}}, "simulation.probes.every_h", "Give a larger value"),
    ],
    ids=["misspelt-key", "no-hours", "unknown-kind", "offset-without-value", "negative-timer"],
)
def test_a_wrong_simulation_key_is_refused_as_the_config_is_read(
    tmp_path: Path, simulation: dict[str, Any], place: str, fix: str
) -> None:
    """``load_config`` (so check-config and run alike) refuses it, naming the key and the fix."""
    with pytest.raises(ConfigFileError) as raised:
        load_config(_simulated(tmp_path, **simulation))
    message = str(raised.value)
    assert f"({place})" in message and fix in message


def test_the_loaded_config_carries_the_checked_section(tmp_path: Path) -> None:
    """What the twin is built from is the section as checked, defaults filled in."""
    config = load_config(_simulated(tmp_path, hours=2))
    assert isinstance(config.simulation, SimulationDoc)
    assert config.simulation.hours == 2 and config.simulation.variant == "reference"
