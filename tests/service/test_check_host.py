"""check-config refuses what would pass and then fail: files a driver names, an INI without offset budget, units.

Each case once passed ``compd check-config`` and then failed at run time
(the OPC UA driver at every reconnect, LinuxCNC at the first write) or
never (a signal in degF fed to a model fitted in degC).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml

from tests.clirun import compd_result

from .daemon_setup import merge, simulated_doc


def check_config(directory: Path, changes: dict[str, Any]) -> tuple[int, str]:
    """``compd check-config`` on the bundled replay config plus ``changes``: exit code and stderr."""
    doc = merge(simulated_doc(), {"state": {"directory": str(directory / "state")}})
    path = directory / "compd.yaml"
    path.write_text(yaml.safe_dump(merge(doc, changes), sort_keys=False))
    code, out, err = compd_result("check-config", path)
    return code, err + out


def opcua_driver(security: Any, **settings: Any) -> dict[str, Any]:
    return {
        "drivers": {
            "cnc": {
                "type": "opcua",
                "settings": {"url": "opc.tcp://127.0.0.1:4840", "security": security, **settings},
            }
        },
        "signals": {"T_spindle_degC": {"driver": "cnc", "address": "ns=2;s=T1"}},
    }


SECURITY = {
    "certificate": "pki/client.pem",
    "private_key": "pki/client.key.pem",
    "server_certificate": "pki/server.der",
}


@pytest.mark.parametrize("key", ["certificate", "private_key", "server_certificate"])
def test_a_missing_opcua_certificate_or_key_is_refused(tmp_path, key):
    """An OPC UA certificate or key file that is not there is refused, naming the key and the file."""
    (tmp_path / "pki").mkdir()
    for name in SECURITY.values():
        (tmp_path / name).write_bytes(b"x")
    (tmp_path / SECURITY[key]).unlink()
    code, text = check_config(tmp_path, opcua_driver(SECURITY))
    assert code != 0
    assert f"drivers.cnc.settings.security.{key}" in text
    assert str(tmp_path / SECURITY[key]) in text and "Put " in text


def test_a_missing_opcua_password_file_is_refused(tmp_path):
    """A password_file that is not there is refused, naming the key and the file; present, the config is ok."""
    (tmp_path / "pki").mkdir()
    for name in SECURITY.values():
        (tmp_path / name).write_bytes(b"x")
    changes = opcua_driver(SECURITY, username="compd", password_file="opcua.password")
    code, text = check_config(tmp_path, changes)
    assert code != 0 and "drivers.cnc.settings.password_file" in text
    assert str(tmp_path / "opcua.password") in text
    (tmp_path / "opcua.password").write_text("secret\n")
    code, text = check_config(tmp_path, changes)
    assert code == 0, text


def test_a_linuxcnc_axis_without_offset_av_ratio_is_refused(tmp_path):
    """With ini_file set, an axis written whose [AXIS_L] lacks OFFSET_AV_RATIO is refused with the line to add."""
    (tmp_path / "mill.ini").write_text(
        "[AXIS_Y]\nMAX_VELOCITY = 2\n[AXIS_Z]\nOFFSET_AV_RATIO = 0.1\n"
    )
    changes = {
        "drivers": {"cnc": {"type": "linuxcnc", "settings": {"ini_file": "mill.ini"}}},
        "outputs": {
            "Y": {"driver": "cnc", "address": "axis.y", "encoding": {"type": "int", "scale": 10}}
        },
        "status": None,
    }
    code, text = check_config(tmp_path, changes)
    assert code != 0 and "drivers.cnc.settings.ini_file" in text
    assert "[AXIS_Y]OFFSET_AV_RATIO is not above 0" in text and "OFFSET_AV_RATIO = 0.1" in text
    changes["outputs"]["Y"]["address"] = "axis.z"
    code, text = check_config(tmp_path, changes)
    assert "OFFSET_AV_RATIO" not in text


@pytest.mark.parametrize(
    ("unit", "fix"),
    [
        ("degF", "'scale: 0.5555555556', 'offset: -17.77777778'"),
        ("K", "'scale: 1', 'offset: -273.15'"),
        ("°C", "Write 'unit: degC' as the model does"),
        ("furlong", "Read the signal in 'degC'"),
    ],
)
def test_a_signal_in_another_unit_than_the_models_is_refused_with_the_conversion(
    tmp_path, unit, fix
):
    """A signal declared in degF, K, °C or an unknown unit where the model reads degC is refused with the fix."""
    code, text = check_config(tmp_path, {"signals": {"T_spindle_degC": {"unit": unit}}})
    assert code != 0
    assert "signals.T_spindle_degC.unit" in text and fix in text


def test_the_bundled_config_still_passes(tmp_path):
    """The replay config as shipped, in the model's units, passes."""
    code, text = check_config(tmp_path, {})
    assert code == 0, text
