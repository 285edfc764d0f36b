"""A config's signal unit against the model file's: what the refusal asks the user to change."""

from __future__ import annotations

from pathlib import Path

import yaml

from tests.acceptance.conftest import machine_doc, write_config
from tests.clirun import compd_result

BUNDLED_MODEL = Path(__file__).resolve().parents[2] / "config" / "simulated_model.yaml"


def test_a_model_without_an_inputs_unit_asks_for_the_unit_in_the_model_file(tmp_path: Path) -> None:
    """A model file that says '-' for a degC signal is refused with the fix in the model file, not 'unit: -'."""
    doc = yaml.safe_load(BUNDLED_MODEL.read_text())
    doc["signals"]["T_headstock_degC"] = {"unit": "-"}
    model = tmp_path / "unitless.yaml"
    model.write_text(yaml.safe_dump(doc, sort_keys=False))
    config = machine_doc(tmp_path, model, simulation={"scenario": "production", "hours": 1})
    code, _, err = compd_result("check-config", write_config(tmp_path, config).path)
    text = " ".join(err.split())
    assert code == 2
    assert "the model file does not say which unit it was fitted in" in text
    assert "write it in the model file's 'signals' section ({unit: degC})" in text
    assert "Do not declare 'unit: -' in the config" in text
