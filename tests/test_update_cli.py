"""``compd update``: named gains re-optimised on probes, written with provenance; bad input exits 2."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from compd.cli import main
from compd.errors import ModelFileError
from compd.files.data import load_data
from compd.files.modelfile import load_model, parse_model
from compd.files.modelwriter import model_to_yaml
from compd.toolkit.evaluate import evaluate
from tests.clirun import compd_result as run

TS = 10.0
TRUE_GAINS = {"g1": 1.4, "g2": 0.6}

MODEL = """\
schema: compd.model/1
name: gated
sample_time_s: 10.0
outputs:
  disp_z_um:
    submodels:
      - name: ambient
        effect: ambient
        input: {{signal: T_ambient_degC}}
        tf: {{form: discrete, power_order: ascending, nk: 1, num: [0.02], den: [1.0, -0.99]}}
      - name: cooling
        effect: spindle, cooling
        input: {{signal: T_spindle_degC}}
        tf: {{form: discrete, power_order: ascending, nk: 1, num: [-0.06], den: [1.0, -0.98]}}
        gain: {g1}
        {name1}
      - name: heating
        effect: spindle, heating minus cooling
        input: {{signal: T_spindle_degC}}
        tf: {{form: discrete, power_order: ascending, nk: 1, num: [-0.05], den: [1.0, -0.95]}}
        gain: {g2}
        {name2}
        gate: {{signal: spindle_speed_rpm, above: 0, applies_to: input}}
"""


def model_text(g1: float = 1.0, g2: float = 1.0, named: bool = True) -> str:
    return MODEL.format(
        g1=g1,
        g2=g2,
        name1="gain_name: g1" if named else "",
        name2="gain_name: g2" if named else "",
    )


@pytest.fixture(scope="module")
def case(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A 12 h record whose displacement is the model with g1 = 1.4, g2 = 0.6, and 30-min probes of it."""
    folder = tmp_path_factory.mktemp("update")
    rng = np.random.default_rng(7)
    n = int(12 * 3600 / TS)
    t = np.arange(n) * TS
    levels = np.repeat(rng.choice([0.0, 3000.0, 6000.0, 9000.0], size=n // 180 + 1), 180)[:n]
    spindle = 22.0 + np.cumsum(np.where(levels > 0, levels / 9e6, -0.0004)).clip(0, None)
    ambient = 20.0 + np.sin(t / 9000.0)
    frame = pd.DataFrame(
        {
            "time_s": t,
            "T_spindle_degC": spindle,
            "T_ambient_degC": ambient,
            "spindle_speed_rpm": levels,
        }
    )
    frame["disp_z_um"] = 0.0
    data_path = folder / "run.csv"
    frame.to_csv(data_path, index=False)
    true = parse_model(model_text(**TRUE_GAINS))
    z = evaluate(true, load_data(data_path)).predicted("disp_z_um")
    frame["disp_z_um"] = z
    frame.to_csv(data_path, index=False, float_format="%.10g")
    model_path = folder / "model.yaml"
    model_path.write_text(model_text())
    every = int(1800 / TS)
    probes = pd.DataFrame({"time_s": t[::every], "disp_z_um": z[::every]})
    probes_path = folder / "probes.csv"
    probes.to_csv(probes_path, index=False, float_format="%.10g")
    return {"folder": folder, "data": data_path, "model": model_path, "probes": probes_path}


def test_update_recovers_the_gains_and_records_what_it_used(case: dict[str, Path]) -> None:
    """Exact probes give back g1, g2; the new file records probes, bounds and before/after figures."""
    out = case["folder"] / "new.yaml"
    code, stdout, err = run(
        "update", case["model"], case["data"], "--probes", case["probes"], "--out", out, "--json"
    )
    assert code == 0, err
    report = json.loads(stdout)
    for key, value in TRUE_GAINS.items():
        assert report["gains"][key]["after"] == pytest.approx(value, rel=1e-4)
        assert report["gains"][key]["bounds"] == [0.0, 2.0]
    assert report["probe_rms_after_um"] < 1e-3 < report["probe_rms_before_um"]
    assert (
        report["fit_percent_after"]["disp_z_um"] > 99.9 > report["fit_percent_before"]["disp_z_um"]
    )

    updated = load_model(out)
    gains = {s.gain_name: s.gain for s in updated.model.outputs[0].submodels if s.gain_name}
    assert gains == pytest.approx(TRUE_GAINS, rel=1e-4)
    (record,) = updated.doc.provenance.updates
    assert record.parent_sha256 == load_model(case["model"]).sha256
    assert record.probes == case["probes"].name  # beside the model: relative to its folder
    assert len(record.probe_times_s) == len(record.probe_values_um["disp_z_um"]) == 24
    assert record.bounds == {"g1": (0.0, 2.0), "g2": (0.0, 2.0)}
    assert record.gains_before == {"g1": 1.0, "g2": 1.0}
    assert record.fit_percent_after["disp_z_um"] == pytest.approx(
        report["fit_percent_after"]["disp_z_um"]
    )
    # The ambient sub-model has no gain name: it is left alone.
    assert updated.model.outputs[0].submodels[0].gain == 1.0
    # What update reports is what the written file does.
    code, stdout, _ = run("compare", out, case["data"], "--json")
    fit = json.loads(stdout)["outputs"]["disp_z_um"]["fit_percent"]
    assert fit == pytest.approx(report["fit_percent_after"]["disp_z_um"], abs=1e-6)


def test_probes_off_the_grid_and_unprobed_cells(case: dict[str, Path]) -> None:
    """Probes between samples are interpolated; empty cells are skipped; the table shows the residues."""
    data = pd.read_csv(case["data"])
    times = np.array([605.0, 7203.0, 15001.0, 22222.0, 30003.0, 40000.0])
    values = np.interp(times, data.time_s, data.disp_z_um)
    lines = ["time_s,disp_z_um"] + [f"{t},{v:.10g}" for t, v in zip(times, values, strict=True)]
    lines.insert(3, "9000,")  # not probed then
    probes = case["folder"] / "offgrid.csv"
    probes.write_text("\n".join(lines) + "\n")
    out = case["folder"] / "offgrid.yaml"
    code, stdout, err = run("update", case["model"], case["data"], "--probes", probes, "--out", out)
    assert code == 0, err
    assert "residue at the probes" in stdout and "g1" in stdout and "wrote" in stdout
    gains = {s.gain_name: s.gain for s in load_model(out).model.outputs[0].submodels if s.gain_name}
    assert gains == pytest.approx(TRUE_GAINS, rel=1e-3)
    (record,) = load_model(out).doc.provenance.updates
    assert record.probe_values_um["disp_z_um"][2] is None


def test_characteristic_bounds_from_a_continuous_run(case: dict[str, Path]) -> None:
    """Eq. 7 on a continuously measured run bounds each gain tightly around its true value."""
    out = case["folder"] / "char.yaml"
    code, stdout, err = run(
        "update", case["model"], case["data"], "--probes", case["probes"], "--out", out,
        "--characteristic-from", case["data"], "--segment-signal", "spindle_speed_rpm", "--json",
    )  # fmt: skip
    assert code == 0, err
    report = json.loads(stdout)
    char = report["characteristic"]
    assert char["segments"] >= 5
    for key, value in TRUE_GAINS.items():
        low, high = char["bounds"][key]
        assert low <= value <= high and high - low < 0.2, (key, low, high)
        assert report["gains"][key]["bounds"] == [low, high]
    assert load_model(out).doc.provenance.updates[0].characteristic is not None


def test_bounds_can_free_a_sub_model_without_a_gain_name(case: dict[str, Path]) -> None:
    """A --bounds key naming a sub-model frees its gain; explicit bounds override the default."""
    out = case["folder"] / "free.yaml"
    code, stdout, err = run(
        "update", case["model"], case["data"], "--probes", case["probes"], "--out", out,
        "--bounds", "ambient=0.5:1.5,g1=1:1.2", "--json",
    )  # fmt: skip
    assert code == 0, err
    gains = json.loads(stdout)["gains"]
    assert set(gains) == {"ambient", "g1", "g2"}
    assert gains["g1"]["bounds"] == [1.0, 1.2] and gains["g1"]["after"] == pytest.approx(1.2)
    assert gains["g1"]["at_bound"]


@pytest.mark.parametrize(
    ("probes", "extra", "expected"),
    [
        ("time_s,disp_z_um\n0,0\n3600,-1\n99999,-2\n", (), ["line 4", "outside"]),
        ("time_s,disp_z_um\n3600,-1\n", (), ["probe at least 2 times"]),
        ("time_s,disp_z_um\n3600,x\n", (), ["line 2, column disp_z_um", "not a number"]),
        ("time_s,disp_y_um\n3600,1\n7200,2\n", (), ["disp_y_um", "name no output"]),
        (None, ("--bounds", "g7=0:2"), ["--bounds", "'g7'", "Use a gain name (g1, g2)"]),
        (None, ("--bounds", "g1=2:1"), ["--bounds", "LOW < HIGH"]),
    ],
    ids=["outside", "too-few", "not-a-number", "unknown-column", "unknown-key", "bad-bound"],
)
def test_bad_input_is_refused_naming_the_place(
    case: dict[str, Path], probes: str | None, extra: tuple[str, ...], expected: list[str]
) -> None:
    """Probes off the record, too few probes, bad cells, unknown columns and bound keys exit 2 with the place."""
    path = case["probes"]
    if probes is not None:
        path = case["folder"] / "bad.csv"
        path.write_text(probes)
    out = case["folder"] / "never.yaml"
    code, _, err = run(
        "update", case["model"], case["data"], "--probes", path, "--out", out, *extra
    )
    assert code == 2
    for text in expected:
        assert text in err
    assert not out.exists()


def test_a_model_without_gain_names_is_refused_with_the_fix(case: dict[str, Path]) -> None:
    """Without gain_name and --bounds there is nothing to update; the error says how to name gains."""
    plain = case["folder"] / "plain.yaml"
    plain.write_text(model_text(named=False))
    code, _, err = run(
        "update", plain, case["data"], "--probes", case["probes"], "--out", plain.with_suffix(".x")
    )
    assert code == 2 and "gain_name: g1" in err and str(plain) in err


def test_gain_names_round_trip_and_a_bad_one_is_refused() -> None:
    """gain_name survives writing and reading; a name with a space is refused at its line."""
    parsed = parse_model(model_text(g1=1.25))
    again = parse_model(model_to_yaml(parsed.model))
    assert [s.gain_name for s in again.model.outputs[0].submodels] == [None, "g1", "g2"]
    assert again.model.outputs[0].submodels[1].gain == 1.25
    with pytest.raises(ModelFileError, match="gain_name"):
        parse_model(model_text().replace("gain_name: g1", "gain_name: g 1"))


def test_help_renders(capsys) -> None:
    """``compd update --help`` renders and documents the probe file and the bounds."""
    with pytest.raises(SystemExit):
        main(["update", "--help"])
    text = capsys.readouterr().out
    assert "--probes" in text and "--bounds" in text and "--characteristic-from" in text


def test_model_check_says_the_recorded_figures_predate_the_update(case: dict[str, Path]) -> None:
    """An updated model's headline was measured before its gains changed: model check says so."""
    fitted = case["folder"] / "fitted.yaml"
    fitted.write_text(
        model_text()
        + "provenance:\n  headline:\n    name: expected fit on new data\n"
        + "    percent: {disp_z_um: 90.0}\n    description: nested cross-validation\n"
    )
    out = case["folder"] / "fitted-updated.yaml"
    code, _, err = run("update", fitted, case["data"], "--probes", case["probes"], "--out", out)
    assert code == 0, err
    code, stdout, _ = run("model", "check", out)
    text = " ".join(stdout.split())
    assert code == 0
    assert "expected fit on new data: 90.0 % (nested cross-validation)" in text
    assert "measured before its 1 update(s): compd update re-optimised gains since" in text
    code, stdout, _ = run("model", "check", fitted)
    assert "update(s)" not in stdout


def test_update_keeps_the_ambient_zero_and_optimises_with_the_bias_it_writes(
    case: dict[str, Path],
) -> None:
    """A model with an ambient zero and a bias keeps both, and the fit update reports is the written file's."""
    parent = case["folder"] / "biased.yaml"
    parent.write_text(
        model_text().replace("    submodels:", "    bias_um: 5.0\n    submodels:", 1)
        + "ambient: {signal: T_ambient_degC, reference: 20.0, moves: [T_spindle_degC]}\n"
    )
    out = case["folder"] / "biased-updated.yaml"
    code, stdout, err = run(
        "update", parent, case["data"], "--probes", case["probes"], "--out", out, "--json"
    )
    assert code == 0, err
    reported = json.loads(stdout)["fit_percent_after"]["disp_z_um"]
    updated = load_model(out)
    assert updated.model.ambient == load_model(parent).model.ambient
    assert updated.model.outputs[0].bias_um == 5.0
    code, stdout, _ = run("compare", out, case["data"], "--json")
    assert json.loads(stdout)["outputs"]["disp_z_um"]["fit_percent"] == pytest.approx(
        reported, abs=1e-6
    )
