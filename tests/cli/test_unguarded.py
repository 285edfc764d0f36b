"""``compd model check`` and ``compd check-config`` say what a model file leaves the daemon without, not a bare ok."""

from __future__ import annotations

from pathlib import Path

import yaml
from structlog.testing import capture_logs

from tests.acceptance.conftest import machine_doc, simulate, write_config
from tests.clirun import compd, compd_result

BUNDLED_MODEL = Path(__file__).resolve().parents[2] / "config" / "simulated_model.yaml"
SIMULATION = {"scenario": "production", "hours": 1, "seed": 1}


def without_calibration(folder: Path) -> Path:
    """The bundled model as a hand-written or older file has it: no calibration ranges, no probe prior."""
    doc = yaml.safe_load(BUNDLED_MODEL.read_text())
    del doc["probe_prior"], doc["provenance"]["calibration"]
    path = folder / "bare-model.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def said(*argv: object) -> str:
    return " ".join(compd(*argv).split())


def test_model_check_notes_a_model_without_envelope_or_probe_prior(tmp_path: Path) -> None:
    """A file without calibration ranges and probe prior: model check names both losses and the fix."""
    text = said("model", "check", without_calibration(tmp_path))
    assert "disp_z_um: the model file records no calibrated range of it" in text
    assert "a daemon's clamp alone judges its offset" in text
    assert (
        "has no probe_prior for it: the probe update starts from the conservative default" in text
    )
    assert text.count("refit with compd fit") == 2
    bundled = said("model", "check", BUNDLED_MODEL)
    assert "no calibrated range" not in bundled and "probe_prior" not in bundled


def test_check_config_says_what_judges_each_axis_offset(tmp_path: Path) -> None:
    """check-config states each axis's calibrated envelope, or that the clamp alone judges its offset."""
    bundled = write_config(tmp_path, machine_doc(tmp_path, BUNDLED_MODEL, simulation=SIMULATION))
    text = said("check-config", bundled.path)
    assert (
        "envelope: disp_z_um -98.38..7.064 um over the calibration, widened by 25% of its span"
        in text
    )
    bare = machine_doc(tmp_path, without_calibration(tmp_path), simulation=SIMULATION)
    text = said("check-config", write_config(tmp_path, bare, "bare.yaml").path)
    assert "records no calibrated range of it" in text
    assert "the clamp (|offset| <= 150 um) alone judges its offset" in text
    bare["safety"] = {"envelope_margin": None}
    text = said("check-config", write_config(tmp_path, bare, "off.yaml").path)
    assert "envelope_margin: null: the clamp (|offset| <= 150 um) alone judges its offset" in text


def test_check_config_says_a_probed_axis_starts_from_the_default_prior(tmp_path: Path) -> None:
    """A probed axis whose model has no probe prior: check-config says the update starts from the default."""
    probes = {"axes": {"Z": None}}
    doc = machine_doc(tmp_path, without_calibration(tmp_path), simulation=SIMULATION, probes=probes)
    text = said("check-config", write_config(tmp_path, doc).path)
    assert "note: disp_z_um: the model file has no probe_prior for it" in text
    doc = machine_doc(tmp_path, BUNDLED_MODEL, simulation=SIMULATION, probes=probes)
    assert "probe_prior" not in said("check-config", write_config(tmp_path, doc, "ok.yaml").path)


def test_model_load_says_what_the_new_model_runs_without(tmp_path: Path) -> None:
    """compd model load of a file without consistency, envelope and probe prior names each loss, the fix with it."""
    doc = machine_doc(tmp_path, BUNDLED_MODEL, simulation=SIMULATION, probes={"axes": {"Z": None}})
    config = write_config(tmp_path, doc)
    bare = yaml.safe_load(without_calibration(tmp_path).read_text())
    del bare["consistency"]
    model = tmp_path / "no-checks.yaml"
    model.write_text(yaml.safe_dump(bare, sort_keys=False))
    code, _, err = compd_result("model", "load", model, "--config", config.path)
    text = " ".join(err.split())
    assert code == 0, err
    assert (
        "no-checks.yaml has no consistency model: the daemon checks its inputs one by one" in text
    )
    assert "records no calibrated range of it" in text and "has no probe_prior for it" in text
    code, _, err = compd_result("model", "load", BUNDLED_MODEL, "--config", config.path)
    assert code == 0 and "note:" not in err, err


def test_the_daemon_warns_when_its_model_has_no_consistency_check_or_envelope(
    tmp_path: Path,
) -> None:
    """A daemon running a model without consistency and calibrated range logs a warning for each."""
    bare = yaml.safe_load(without_calibration(tmp_path).read_text())
    del bare["consistency"]
    model = tmp_path / "no-checks.yaml"
    model.write_text(yaml.safe_dump(bare, sort_keys=False))
    config = write_config(tmp_path, machine_doc(tmp_path, model, simulation=SIMULATION))
    with capture_logs() as logs:
        simulate(config, duration_s=5.0)
    warned = [e for e in logs if e["log_level"] == "warning" and "consistency" in e["event"]]
    assert warned and warned[0]["model"] == "twin-z", logs
    (clamp,) = [e for e in logs if e["event"].startswith("the model file records no calibrated")]
    assert clamp["log_level"] == "warning" and clamp["axis"] == "Z" and "compd fit" in clamp["fix"]


def test_an_input_the_consistency_model_does_not_predict_is_named(tmp_path: Path) -> None:
    """A model input outside the consistency checks (as compd extend adds one): model check and check-config name it."""
    doc = yaml.safe_load(BUNDLED_MODEL.read_text())
    doc["consistency"]["checked"].remove("T_headstock_degC")
    for key in ("sigma", "max_rate_per_s"):
        doc["consistency"][key].pop("T_headstock_degC", None)
    model = tmp_path / "partly.yaml"
    model.write_text(yaml.safe_dump(doc, sort_keys=False))
    expected = "not checked against the other signals: T_headstock_degC (model inputs its"
    assert expected in said("model", "check", model)
    config = write_config(tmp_path, machine_doc(tmp_path, model, simulation=SIMULATION))
    assert expected in said("check-config", config.path)
    assert "not checked against" not in said("model", "check", BUNDLED_MODEL)


def test_a_model_input_without_a_range_check_is_named(tmp_path: Path) -> None:
    """check-config names a model input read without checks min and max, and what then catches a broken sensor."""
    doc = machine_doc(tmp_path, BUNDLED_MODEL, simulation=SIMULATION)
    del doc["signals"]["T_headstock_degC"]["checks"]["max"]
    text = said("check-config", write_config(tmp_path, doc).path)
    assert "no range check on model input(s) T_headstock_degC (checks min and max)" in text
    assert "only the check against the other signals catches" in text
    doc["plausibility"] = {"enabled": False}
    text = said("check-config", write_config(tmp_path, doc, "off.yaml").path)
    assert "nothing catches (no check against the other signals either)" in text
    bundled = machine_doc(tmp_path, BUNDLED_MODEL, simulation=SIMULATION)
    assert "no range check" not in said(
        "check-config", write_config(tmp_path, bundled, "ok.yaml").path
    )
