"""What a config's sensors cannot verify of its model: the axis tolerance, check-config, status and /metrics."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest
import yaml

from compd.cli import main
from compd.cli.status import unverifiable_line
from compd.errors import ConfigFileError
from compd.files.modelfile import load_model
from compd.files.yamlplace import resolve_path
from compd.service.config.loading import Config, load_config
from compd.service.config.verifiable import (
    axis_tolerances_um,
    config_unverifiable,
    redundant_partners,
)
from compd.service.daemon import Service
from compd.service.http.metrics import LiveCollector
from compd.service.loop.clock import VirtualClock

SIMULATED = resolve_path("bundled:simulated.yaml", Path("."))
MODEL = resolve_path("bundled:simulated_model.yaml", Path("."))


def config(tmp_path: Path, **changes: Any) -> Config:
    """The bundled simulated-machine config, its state under ``tmp_path``, with ``changes``."""
    doc = yaml.safe_load(SIMULATED.read_text())
    doc["model"] = str(MODEL)
    doc["state"] = {"directory": str(tmp_path / "state")}
    doc["recorder"] = {"enabled": False}
    doc["control_socket"] = str(tmp_path / "c.sock")
    for key, value in changes.items():
        doc[key] = value
    path = tmp_path / "compd.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return load_config(path)


def rows_of(cfg: Config) -> dict[str, Any]:
    model_file = load_model(cfg.model_path)
    rows = config_unverifiable(cfg.doc, model_file, model_file.compile(cfg.doc.period_s))
    return {r.input: r for r in rows}


def test_an_axis_tolerance_defaults_to_three_calibration_rms_and_may_be_given(
    tmp_path: Path,
) -> None:
    """Without ``tolerance_um``: 3 x the model's calibration RMS residue of the axis's output; given: as given."""
    cfg = config(tmp_path)
    model_file = load_model(cfg.model_path)
    assert model_file.doc.provenance.calibration is not None
    rms = model_file.doc.provenance.calibration.rms_um["disp_z_um"]
    assert axis_tolerances_um(cfg.doc, model_file) == {"Z": pytest.approx(3 * rms)}
    outputs = yaml.safe_load(SIMULATED.read_text())["outputs"]
    outputs["Z"]["tolerance_um"] = 120.0
    given = config(tmp_path, outputs=outputs)
    assert axis_tolerances_um(given.doc, model_file) == {"Z": 120.0}
    assert not rows_of(given)["T_ambient_degC"].exceeds  # within 120


@pytest.mark.parametrize("bad", [0, -1, ".inf", "1e308"])
def test_a_tolerance_that_is_not_a_sensible_length_is_a_config_error_naming_the_key(
    tmp_path: Path, bad: str
) -> None:
    """``outputs.Z.tolerance_um`` must be above 0 and at most 10 mm: else the error names the key."""
    text = SIMULATED.read_text().replace(
        "    max_offset_um: 150\n", f"    max_offset_um: 150\n    tolerance_um: {bad}\n"
    )
    path = tmp_path / "compd.yaml"
    path.write_text(text.replace("model: simulated_model.yaml", f"model: {MODEL}"))
    with pytest.raises(ConfigFileError, match=r"outputs\.Z\.tolerance_um"):
        load_config(path)


def test_with_plausibility_off_no_input_is_verified(tmp_path: Path) -> None:
    """``plausibility.enabled: false`` and one sensor each: nothing judges an input, every weight is unseen."""
    rows = rows_of(config(tmp_path, plausibility={"enabled": False}, signals=one_sensor_each()))
    assert all(math.isinf(r.undetectable_um) and r.exceeds for r in rows.values())
    assert "plausibility is off" in rows["T_spindle_degC"].detection.by


def one_sensor_each() -> dict[str, Any]:
    """The bundled config's signals without the second spindle and air sensors."""
    signals = yaml.safe_load(SIMULATED.read_text())["signals"]
    for name in ("T_spindle_b_degC", "T_ambient_b_degC"):
        signals.pop(name)
    for signal in signals.values():
        signal.pop("redundant", None)
    return signals


def test_check_config_prints_what_can_be_verified_and_still_exits_0(capsys: Any) -> None:
    """The bundled config: its spindle and air are verified by their second sensors; exit status 0."""
    assert main(["check-config", "bundled:simulated.yaml"]) == 0
    out = capsys.readouterr().out
    assert "what the sensors can verify" in out
    spindle = next(line for line in out.splitlines() if line.startswith("│ T_spindle_degC"))
    assert "its redundant partner T_spindle_b_degC" in spindle and "ok" in spindle
    assert "every input is verified to its axis's tolerance" in out


def test_check_config_names_the_remedy_where_an_input_cannot_be_verified(
    tmp_path: Path, capsys: Any
) -> None:
    """One sensor each: the spindle is checked by the others only to 4.4 sigma (the drift CUSUM's
    smallest lasting step), 6.9 degC or about 53 um on Z: a redundant sensor or probes."""
    cfg = config(tmp_path, signals=one_sensor_each())
    assert main(["check-config", str(cfg.path)]) == 0
    out = capsys.readouterr().out
    spindle = next(line for line in out.splitlines() if line.startswith("│ T_spindle_degC"))
    assert "6.88" in spindle and "53.4" in spindle and "redundant sensor" in spindle
    assert "cannot be verified to the axis's tolerance" in out


def test_model_check_prints_it_with_defaults_and_says_so(capsys: Any) -> None:
    """Without a config: the default settings and every logged signal, said in a note."""
    assert main(["model", "check", "bundled:simulated_model.yaml"]) == 0
    out = capsys.readouterr().out
    assert "what the sensors can verify" in out and "no config: the default plausibility" in out


def test_status_and_metrics_carry_what_cannot_be_verified(tmp_path: Path) -> None:
    """``compd status``'s JSON and line, and ``compd_unverifiable_error_meters``, give the same figures."""
    cfg = config(tmp_path, signals=one_sensor_each())
    service = Service(cfg, clock=VirtualClock(), control=False)
    rows = {r["input"]: r for r in service.status()["unverifiable"]}
    spindle = rows["T_spindle_degC"]
    assert spindle["axis"] == "Z" and spindle["unit"] == "degC" and not spindle["verifiable"]
    assert spindle["undetectable_um"] == pytest.approx(53.4, abs=0.5)
    assert rows["T_headstock_degC"]["verifiable"]
    line = unverifiable_line(spindle).plain
    assert line.startswith("  not verifiable: T_spindle_degC 53 um on Z")
    assert "redundant sensor" in line and "probes on Z" in line

    (gauge,) = [
        m for m in LiveCollector(service).collect() if m.name == "compd_unverifiable_error_meters"
    ]
    samples = {s.labels["input"]: s.value for s in gauge.samples}
    assert samples["T_spindle_degC"] == pytest.approx(spindle["undetectable_um"] * 1e-6)
    assert set(samples) == set(rows)


def test_an_input_with_a_second_sensor_is_verified_to_the_step_its_pair_catches(
    tmp_path: Path,
) -> None:
    """The bundled pairs (tolerance 0.5 degC): a lasting step of twice the pair's allowance
    (0.15 x 0.5 = 0.075 degC) is caught within 400 s, so that is the spindle's threshold."""
    cfg = config(tmp_path)
    assert redundant_partners(cfg.doc) == {
        "T_spindle_degC": ("T_spindle_b_degC", pytest.approx(0.15)),
        "T_ambient_degC": ("T_ambient_b_degC", pytest.approx(0.15)),
    }
    rows = rows_of(cfg)
    assert rows["T_spindle_degC"].detection.threshold == pytest.approx(0.15)
    assert rows["T_spindle_degC"].undetectable_um == pytest.approx(0.15 * 7.766, abs=0.01)
    assert not rows["T_spindle_degC"].exceeds
    assert config(tmp_path, signals=one_sensor_each()).doc.pairs() == []
