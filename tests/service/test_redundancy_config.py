"""A signal's second sensor (``redundant:``) in the config: what is accepted, what is refused and how."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml

from compd.errors import ConfigFileError
from compd.files.modelfile import load_model
from compd.files.yamlplace import resolve_path
from compd.service.config.docs import DEFAULT_REDUNDANT_TOLERANCE
from compd.service.config.modelcheck import check_model
from compd.service.loop.redundancy import Pair

from .daemon_setup import write_config

SIMULATED_MACHINE = resolve_path("bundled:simulated.yaml", Path("."))


def machine_doc() -> dict[str, Any]:
    doc: dict[str, Any] = yaml.safe_load(SIMULATED_MACHINE.read_text())
    return doc


def refused(tmp_path: Path, doc: dict[str, Any]) -> str:
    with pytest.raises(ConfigFileError) as caught:
        write_config(tmp_path, doc=doc)
    return str(caught.value)


def test_the_bundled_machine_pairs_its_spindle_and_air_sensors(tmp_path):
    """The simulated machine's config names a second sensor for the spindle and the air, 0.5 degC apart at most."""
    assert write_config(tmp_path, doc=machine_doc()).doc.pairs() == [
        Pair("T_spindle_degC", "T_spindle_b_degC", DEFAULT_REDUNDANT_TOLERANCE, "degC"),
        Pair("T_ambient_degC", "T_ambient_b_degC", DEFAULT_REDUNDANT_TOLERANCE, "degC"),
    ]


def test_a_partner_that_is_not_a_signal_is_refused_naming_the_key(tmp_path):
    """``redundant:`` naming no signal: refused at signals.<name>.redundant, with the signals to choose from."""
    doc = machine_doc()
    doc["signals"]["T_spindle_degC"]["redundant"] = "T_spindle_c_degC"
    message = refused(tmp_path, doc)
    assert "(signals.T_spindle_degC.redundant)" in message
    assert "'T_spindle_c_degC' is not defined under 'signals'" in message and "Define" in message


def test_a_partner_in_another_unit_is_refused(tmp_path):
    """A pair reads one point in one unit: a partner in K beside a degC input is refused."""
    doc = machine_doc()
    doc["signals"]["T_spindle_b_degC"]["unit"] = "K"
    message = refused(tmp_path, doc)
    assert "(signals.T_spindle_degC.redundant)" in message and "same unit" in message


@pytest.mark.parametrize(
    ("change", "says"),
    [
        ({"T_spindle_b_degC": {"redundant": "T_headstock_degC"}}, "names a partner of its own"),
        ({"T_ambient_degC": {"redundant": "T_spindle_b_degC"}}, "already the partner of"),
        ({"T_spindle_degC": {"redundant": "T_spindle_degC"}}, "names itself"),
        ({"T_headstock_degC": {"redundant_tolerance": 0.3}}, "names no partner"),
    ],
    ids=["partner-of-partner", "shared-partner", "itself", "tolerance-alone"],
)
def test_pairs_are_one_input_and_one_second_sensor(tmp_path, change, says):
    """A partner naming a partner, one partner for two inputs, a signal its own partner, a lone tolerance: refused."""
    doc = machine_doc()
    for name, keys in change.items():
        doc["signals"][name] |= keys
    assert says in refused(tmp_path, doc)


def test_a_pair_in_a_unit_without_a_default_needs_its_tolerance(tmp_path):
    """Two speed sensors may pair only with a tolerance given in their unit; temperatures have a default."""
    doc = machine_doc()
    doc["signals"]["spindle_speed_b_rpm"] = {**doc["signals"]["spindle_speed_rpm"]}
    doc["signals"]["spindle_speed_b_rpm"]["address"] = "input:8:uint16"
    doc["status"]["status_address"] = "holding:110:uint32"
    doc["signals"]["spindle_speed_rpm"]["redundant"] = "spindle_speed_b_rpm"
    assert "redundant_tolerance" in refused(tmp_path, doc)
    doc["signals"]["spindle_speed_rpm"]["redundant_tolerance"] = 50
    config = write_config(tmp_path, doc=doc)
    assert Pair("spindle_speed_rpm", "spindle_speed_b_rpm", 50, "rpm") in config.doc.pairs()


def test_a_partner_the_model_reads_is_refused(tmp_path):
    """A second sensor stands in for a model input; one the model reads itself is refused at model check."""
    doc = machine_doc()
    doc["signals"]["T_headstock_degC"]["redundant"] = "T_column_front_degC"
    doc["model"] = str(resolve_path("bundled:simulated_model.yaml", Path(".")))
    config = write_config(tmp_path, doc=doc)
    model_file = load_model(config.model_path)
    with pytest.raises(ConfigFileError, match=r"signals\.T_headstock_degC\.redundant.*is an input"):
        check_model(config, model_file, model_file.compile(1.0))
