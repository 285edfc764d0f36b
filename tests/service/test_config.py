"""The daemon config: the bundled configs validate; every error names file, line, place and fix."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml

from compd.drivers.gateway.driver import GatewayDriver
from compd.drivers.gateway.settings import GatewaySettings
from compd.drivers.modbus.driver import ModbusDriver
from compd.drivers.modbus.settings import ModbusSettings
from compd.errors import ConfigFileError
from compd.files.modelfile import load_model
from compd.files.yamlplace import resolve_path
from compd.service.config.loading import load_config, parse_config
from compd.service.config.modelcheck import check_model

from .daemon_setup import BUNDLED_SIMULATED, simulated_doc, write_config

EXAMPLE = resolve_path("bundled:compd.example.yaml", Path("."))


@pytest.mark.parametrize(
    "path",
    [BUNDLED_SIMULATED, EXAMPLE, resolve_path("bundled:simulated.yaml", Path("."))],
    ids=["replay", "example", "simulated"],
)
def test_bundled_configs_validate_with_their_models(path):
    """The bundled service configs pass the same checks as compd run makes."""
    config = load_config(path)
    model_file = load_model(config.model_path)
    check_model(config, model_file, model_file.compile(config.doc.period_s))
    assert config.doc.drivers and config.doc.outputs


def test_config_objects_are_frozen(tmp_path):
    """A validated config cannot be changed afterwards."""
    config = write_config(tmp_path)
    with pytest.raises(ValueError, match="frozen"):
        config.doc.signals["T_spindle_degC"].scale = 2.0


def error_for(tmp_path: Path, text: str) -> str:
    path = tmp_path / "bad.yaml"
    with pytest.raises(ConfigFileError) as info:
        parse_config(text, path)
    return str(info.value)


def bundled_text_with(old: str, new: str) -> str:
    text = BUNDLED_SIMULATED.read_text()
    assert old in text
    return text.replace(old, new, 1)


def test_unknown_key_names_line_place_and_fix(tmp_path):
    """A misspelt key is reported with its file, line, dotted place and a fix."""
    text = bundled_text_with("    unit: degC\n", "    unti: degC\n")
    line = text.splitlines().index("    unti: degC") + 1
    message = error_for(tmp_path, text)
    assert message.startswith(
        f"{tmp_path / 'bad.yaml'}: line {line} (signals.T_spindle_degC.unti): "
    )
    assert "unknown key 'unti'" in message and "Remove the key or fix its spelling" in message


def test_signal_naming_an_undefined_driver(tmp_path):
    """A signal whose driver is not defined names the place and the defined drivers."""
    text = bundled_text_with(
        "    driver: machine\n    address: T_spindle_degC",
        "    driver: plc\n    address: T_spindle_degC",
    )
    message = error_for(tmp_path, text)
    assert "(signals.T_spindle_degC.driver): driver 'plc' is not defined under 'drivers'" in message
    assert "Define it or use one of ['machine']" in message


def test_wrong_type_is_refused(tmp_path):
    """A value of the wrong type names its place and asks for a number."""
    message = error_for(tmp_path, bundled_text_with("max_offset_um: 50", "max_offset_um: lots"))
    assert "(outputs.Y.max_offset_um)" in message and "Give a number" in message


def test_driver_settings_are_validated_by_the_driver(tmp_path):
    """A driver's own settings schema is applied at load, with the place under drivers.<name>.settings."""
    message = error_for(
        tmp_path, bundled_text_with("      loop: true", "      loop: true\n      speed: 3")
    )
    assert "(drivers.machine.settings.speed): unknown key 'speed'" in message


def test_unknown_driver_type(tmp_path):
    """A driver type that is neither built in nor installed is refused with the known types."""
    message = error_for(tmp_path, bundled_text_with("type: simulated", "type: modbus-ascii"))
    assert "(drivers.machine.type): unknown driver type 'modbus-ascii'" in message
    assert "'simulated'" in message


def test_two_values_written_to_one_address(tmp_path):
    """The status word cannot share an address with an axis offset."""
    message = error_for(
        tmp_path, bundled_text_with("status_address: compd_status", "status_address: comp_y_um")
    )
    assert (
        "(status.status_address): address 'comp_y_um' on driver 'machine' is already written "
        "at line 44 (outputs.Y.address)" in message
    )


def test_missing_schema(tmp_path):
    """A file without the schema line says which schema to write."""
    assert "Start the file with 'schema: compd.config/1'" in error_for(tmp_path, "model: x.yaml\n")


def test_model_input_without_a_signal(tmp_path):
    """A model reading a signal the config does not define is refused before start-up."""
    doc = simulated_doc()
    doc["signals"]["spindle_rpm"] = doc["signals"].pop("spindle_speed_rpm")
    config = write_config(tmp_path, doc=doc)
    model_file = load_model(config.model_path)
    with pytest.raises(
        ConfigFileError, match=r"reads signal\(s\) \['spindle_speed_rpm'\] that are not defined"
    ):
        check_model(config, model_file, model_file.compile(1.0))


def test_axis_naming_a_missing_model_output(tmp_path):
    """An axis mapped to an output the model does not have is refused, listing the model's outputs."""
    config = write_config(tmp_path, {"outputs": {"Y": {"model_output": "disp_q_um"}}})
    model_file = load_model(config.model_path)
    with pytest.raises(
        ConfigFileError, match=r"outputs.Y.model_output.*Use one of \['disp_y_um'\]"
    ):
        check_model(config, model_file, model_file.compile(1.0))


def test_recorder_total_must_hold_one_file(tmp_path):
    """A recorder total limit below one file's limit is refused at load, naming the recorder section."""
    text = (
        BUNDLED_SIMULATED.read_text()
        + "recorder: {max_file_bytes: 100000, max_total_bytes: 50000}\n"
    )
    message = error_for(tmp_path, text)
    assert "(recorder)" in message and "must be at least 'max_file_bytes'" in message


def test_an_offset_on_a_read_only_sensor_driver_is_refused(tmp_path):
    """check-config refuses an axis written through a serial scanner, naming the place and the fix."""
    scanner = {"type": "serial_sensor", "settings": {"port": "/dev/ttyUSB0", "channels": ["1"]}}
    changes = {
        "drivers": {"scanner": scanner},
        "outputs": {"Y": {"driver": "scanner", "address": "1"}},
    }
    with pytest.raises(ConfigFileError) as caught:
        write_config(tmp_path, changes)
    text = str(caught.value)
    assert "outputs.Y.address" in text and "read-only" in text and "writable driver" in text


SIMULATED_MACHINE = resolve_path("bundled:simulated.yaml", Path("."))


def machine_config_error(tmp_path: Path, changes: dict) -> str:
    """The error for the bundled simulated-machine config (Modbus, Z int32 at holding:100) with ``changes``."""
    with pytest.raises(ConfigFileError) as caught:
        write_config(tmp_path, changes, doc=yaml.safe_load(SIMULATED_MACHINE.read_text()))
    return str(caught.value)


def test_a_status_word_inside_an_int32_offset_is_refused(tmp_path):
    """A status word at holding:101 overlaps the int32 offset at holding:100-101: refused, naming both."""
    message = machine_config_error(tmp_path, {"status": {"status_address": "holding:101"}})
    assert re.search(
        r"\(status\.status_address\): address 'holding:101' on driver 'plc' overlaps "
        r"'holding:100:int32' on driver 'plc', written at line \d+ \(outputs\.Z\.address\)",
        message,
    )


@pytest.mark.parametrize(
    ("status", "unit_ids"),
    [("holding:102", "shared"), ("holding:101:device=2", "separate")],
    ids=["next-register", "other-device"],
)
def test_written_points_in_other_registers_or_devices_pass(tmp_path, status, unit_ids):
    """Written points that share no register of one device (unit ids declared separate) are accepted."""
    doc = yaml.safe_load(SIMULATED_MACHINE.read_text())
    doc["drivers"]["plc"]["settings"]["unit_ids"] = unit_ids
    config = write_config(tmp_path, {"status": {"status_address": status}}, doc=doc)
    assert config.doc.status.status_address == status


def test_modbus_tables_are_separate_areas():
    """Coil 100 and holding register 100 are different cells; holding 101 is inside an int32 at 100."""
    settings = ModbusSettings(host="127.0.0.1")
    int32 = ModbusDriver.footprint("holding:100:int32", settings)
    assert not ModbusDriver.footprint("coil:100", settings) & int32
    assert ModbusDriver.footprint("holding:101", settings) <= int32


def gateway_doc() -> dict:
    """The simulated-machine config on a Profibus gateway over Modbus TCP: 16-byte areas."""
    doc = yaml.safe_load(SIMULATED_MACHINE.read_text())
    doc["drivers"]["plc"] = {
        "type": "profibus_gateway",
        "settings": {"host": "127.0.0.1", "input_bytes": 16, "output_bytes": 16},
    }
    for i, signal in enumerate(doc["signals"].values()):
        signal["address"] = f"in:{2 * i}:int16"
    doc["outputs"]["Z"]["address"] = "out:0:int32"
    doc["status"] = {
        "driver": "plc",
        "status_address": "out:4:uint16",
        "heartbeat_address": "out:6:uint16",
    }
    return doc


def test_gateway_bytes_overlap_per_area(tmp_path):
    """On a gateway a value inside another's output bytes is refused; the same offset in the input area is not."""
    doc = gateway_doc()
    assert write_config(tmp_path, doc=doc).doc.status.status_address == "out:4:uint16"
    doc["status"]["status_address"] = "out:2:uint16"
    with pytest.raises(ConfigFileError, match=r"overlaps 'out:0:int32' on driver 'plc', written"):
        write_config(tmp_path, doc=doc)
    settings = GatewaySettings.model_validate(doc["drivers"]["plc"]["settings"])
    int32 = GatewayDriver.footprint("out:0:int32", settings)
    assert not GatewayDriver.footprint("in:0:int32", settings) & int32
    assert GatewayDriver.footprint("out:3.7", settings) <= int32


def test_an_integer_offset_coarser_than_a_slew_step_is_refused(tmp_path):
    """Whole micrometres (scale 1) at 0.5 um/s would step 1 um at a time: refused with the scale that works."""
    slow = {"encoding": {"type": "int", "scale": 1}, "max_rate_um_per_s": 0.5}
    message = machine_config_error(tmp_path, {"outputs": {"Z": slow}})
    assert "(outputs.Z.encoding.scale): an integer count of 1 um (scale 1) is coarser" in message
    assert "Use scale >= 2" in message
    doc = yaml.safe_load(SIMULATED_MACHINE.read_text())
    fine = {"encoding": {"type": "int", "scale": 2}, "max_rate_um_per_s": 0.5}
    write_config(tmp_path, {"outputs": {"Z": fine}}, doc=doc)  # one count per step is fine
    floats = {"encoding": {"type": "float", "scale": 1}, "max_rate_um_per_s": 0.01}
    message = machine_config_error(tmp_path, {"outputs": {"Z": floats}})  # int32 rounds it anyway
    assert "(outputs.Z.encoding.scale): a count of the register of 1 um" in message
    floats["address"] = "holding:100:float32"
    write_config(tmp_path, {"outputs": {"Z": floats}}, doc=doc)


def test_values_that_cannot_fit_their_registers_are_refused(tmp_path):
    """An int16 offset in 0.001 um cannot reach 150 um; a coil cannot carry the status word's 15 bits."""
    message = machine_config_error(
        tmp_path, {"outputs": {"Z": {"address": "holding:100:int16", "encoding": {"scale": 1000}}}}
    )
    assert "(outputs.Z.address): 'holding:100:int16' holds -32768..32767" in message
    assert "±150000" in message
    message = machine_config_error(tmp_path, {"status": {"status_address": "coil:110"}})
    assert (
        "(status.status_address): 'coil:110' holds 0..1, but it must carry bits 0..15 "
        "(up to 65535) for 8 signals" in message
    )


def test_readback_is_on_where_the_driver_can_read_back(tmp_path):
    """Modbus offsets read back by default, unless 'readback: false'; the replay driver cannot, and says so."""
    doc = yaml.safe_load(SIMULATED_MACHINE.read_text())
    assert write_config(tmp_path, doc=doc).readback == {"Z": True}
    off = write_config(tmp_path, {"outputs": {"Z": {"readback": False}}}, doc=doc)
    assert off.readback == {"Z": False}
    assert write_config(tmp_path).readback == {"Y": False}  # the replay (simulated) driver
    with pytest.raises(ConfigFileError) as caught:
        write_config(tmp_path, {"outputs": {"Y": {"readback": True}}})
    assert "(outputs.Y.readback): driver 'machine' (type simulated) cannot read back" in str(
        caught.value
    )


def test_the_mismatch_bit_is_used_only_where_the_status_register_holds_it(tmp_path):
    """Six signals leave bit 14 of a uint16 status word for the mismatch; eight leave none; nine do not fit."""
    doc = yaml.safe_load(SIMULATED_MACHINE.read_text())
    assert write_config(tmp_path, doc=doc).mismatch_bit == 16  # eight signals, a uint32 word
    doc["status"]["status_address"] = "holding:110"
    for name in ("T_spindle_degC", "T_ambient_degC"):
        doc["signals"][doc["signals"][name].pop("redundant")] = None
    doc["signals"] = {name: s for name, s in doc["signals"].items() if s is not None}
    assert write_config(tmp_path, doc=doc).mismatch_bit == 14
    extra = {"driver": "plc", "unit": "degC", "scale": 0.01}
    doc["signals"] |= {f"T_{i}_degC": {**extra, "address": f"input:{i}:int16"} for i in (6, 7)}
    assert write_config(tmp_path, doc=doc).mismatch_bit is None
    doc["signals"]["T_8_degC"] = {**extra, "address": "input:8:int16"}
    with pytest.raises(ConfigFileError, match=r"must carry bits 0\.\.16"):
        write_config(tmp_path, doc=doc)
