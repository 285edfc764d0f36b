"""``compd compare --probe-every`` / ``--probes``: the model updated at probes, judged between them beside open loop."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
import scipy.signal

from compd.cli import main
from compd.files.modelfile import load_model
from tests.model.thermal_cases import held_levels, thermal_second_order

TS = 10.0


def _record(path, *, hours: float, heat_gain: float, seed: int) -> None:
    """Spindle and ambient temperatures, the displacement they cause and what they do not explain.

    ``heat_gain`` scales the spindle's share.
    """
    rng = np.random.default_rng(seed)
    n = int(hours * 3600 / TS)
    spindle = 22.0 + held_levels(rng, n, TS)
    ambient = 20.0 + 0.3 * held_levels(rng, n, TS, lag_s=3600.0)
    heat_b, heat_a = thermal_second_order((1200.0, 4800.0), 3.0 * heat_gain, 0.4, TS)
    amb_b, amb_a = thermal_second_order((2400.0, 7200.0), -2.0, 0.5, TS)
    z = scipy.signal.lfilter(heat_b, heat_a, spindle - spindle[0]) + scipy.signal.lfilter(
        amb_b, amb_a, ambient - ambient[0]
    )
    # What no model of these two inputs explains (about 0.5 um, slow), and the gauge's noise.
    z += 0.5 * np.convolve(rng.standard_normal(n), np.ones(180) / np.sqrt(180), mode="same")
    z += 0.05 * rng.standard_normal(n)
    frame = {"time_s": np.arange(n) * TS, "T_spindle_degC": spindle, "T_ambient_degC": ambient}
    pd.DataFrame(frame | {"disp_z_um": z}).to_csv(path, index=False, float_format="%.9g")


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    """A model fitted on 24 h of one machine, and 12 h of the same machine whose spindle now heats 1.4x as much."""
    folder = tmp_path_factory.mktemp("probes")
    _record(folder / "calib.csv", hours=24, heat_gain=1.0, seed=21)
    _record(folder / "later.csv", hours=12, heat_gain=1.4, seed=22)
    model = folder / "model.yaml"
    assert main(["fit", "--data", str(folder / "calib.csv"), "--output", "disp_z_um",
                 "--inputs", "T_spindle_degC,T_ambient_degC", "--out", str(model)]) == 0  # fmt: skip
    return folder, model


def _compare(capsys, model, data, *options):
    assert main(["compare", str(model), str(data), "--json", *options]) == 0
    return json.loads(capsys.readouterr().out)


def test_fit_stores_the_calibrations_prior(case) -> None:
    """``compd fit`` writes the probe_prior block: the sub-models and bias, an SPD covariance, n_eff below n."""
    _, model = case
    doc = load_model(model).doc
    assert doc.probe_prior is not None
    prior = doc.probe_prior["disp_z_um"]
    assert prior.parameters[-1] == "bias"
    assert len(prior.parameters) == 1 + len(doc.outputs["disp_z_um"].submodels)
    assert np.all(np.linalg.eigvalsh(np.array(prior.covariance)) > 0)
    assert 1 <= prior.effective_samples < prior.samples
    assert prior.output_peak_um > 0
    # The residue's transient variance per probe interval: 15 min to 8 h of a 24 h calibration,
    # growing with the interval, within the residue's own variance.
    transient = prior.transient_variance_um2
    assert transient is not None and sorted(transient) == [900, 1800, 3600, 7200, 14400, 28800]
    values = [transient[k] for k in sorted(transient)]
    assert values == sorted(values) and 0 < values[-1] <= prior.residue_sigma_um**2 * 1.01


def test_probes_every_2h_beat_open_loop_on_a_changed_machine(case, capsys) -> None:
    """With a probe every 2 h the error between the probes is below the open-loop error."""
    folder, model = case
    summary = _compare(capsys, model, folder / "later.csv", "--probe-every", "2h", "--seed", "3")
    figures = summary["outputs"]["disp_z_um"]
    assert figures["prior"] == "calibration"
    assert summary["notes"] == []
    times = {p["time_s"] for p in figures["probes"]}
    scheduled = {h * 3600.0 for h in (2, 4, 6, 8, 10)}  # 12 h is past the end
    assert scheduled <= times
    # A flagged probe leaves the probe due: the PLC probes again 15 min later.
    flagged = {p["time_s"] for p in figures["probes"] if p["result"] == "flagged"}
    assert times - scheduled == {t + 900.0 for t in flagged if t + 900.0 not in scheduled}
    assert figures["with_probes"]["rms_um"] < 0.85 * figures["open_loop"]["rms_um"]


def test_probes_from_a_file_and_a_mis_probe(case, capsys, tmp_path) -> None:
    """Probes from a file: a value 50 um off is flagged, rejected when the next agrees, and changes nothing."""
    folder, model = case
    data = pd.read_csv(folder / "later.csv")
    at = [3600.0, 7200.0, 10800.0, 14400.0, 18000.0]
    values = [float(data.loc[data.time_s == t, "disp_z_um"].iloc[0]) for t in at]
    probes = tmp_path / "probes.csv"
    pd.DataFrame({"time_s": at, "disp_z_um": values}).to_csv(probes, index=False)
    clean = _compare(capsys, model, folder / "later.csv", "--probes", str(probes))
    values[2] += 50.0
    pd.DataFrame({"time_s": at, "disp_z_um": values}).to_csv(probes, index=False)
    mis = _compare(capsys, model, folder / "later.csv", "--probes", str(probes))
    steps = [p["result"] for p in mis["outputs"]["disp_z_um"]["probes"]]
    assert steps == ["accepted", "accepted", "flagged", "rejected", "accepted", "accepted"]
    # The mis-probe changed nothing: the run equals one without that probe (the same median
    # spacing, 1 h: the interval the update assumes for probes from a file).
    keep = [0, 1, 3, 4]
    pd.DataFrame({"time_s": [at[k] for k in keep], "disp_z_um": [values[k] for k in keep]}).to_csv(
        probes, index=False
    )
    without = _compare(capsys, model, folder / "later.csv", "--probes", str(probes))
    rms = [s["outputs"]["disp_z_um"]["with_probes"]["rms_um"] for s in (mis, without)]
    assert rms[0] == pytest.approx(rms[1], rel=1e-9)
    assert clean["outputs"]["disp_z_um"]["open_loop"] == mis["outputs"]["disp_z_um"]["open_loop"]


def test_a_model_file_without_the_prior_uses_the_default_and_says_so(
    case, capsys, tmp_path
) -> None:
    """Without a probe_prior block: the conservative default, named in the notes and the JSON."""
    folder, model = case
    text = model.read_text()
    start = text.index("\nprobe_prior:")
    end = text.index("\nprovenance:", start)
    bare = tmp_path / "bare.yaml"
    bare.write_text(text[:start] + text[end:])
    summary = _compare(capsys, bare, folder / "later.csv", "--probe-every", "2h")
    assert summary["outputs"]["disp_z_um"]["prior"] == "default"
    (note,) = summary["notes"]
    assert "conservative default" in note and "gain 1 +- 0.3" in note
    assert main(["compare", str(bare), str(folder / "later.csv"), "--probe-every", "2h"]) == 0
    assert "conservative default" in capsys.readouterr().err


def test_probes_with_a_report_are_refused(case, capsys) -> None:
    """--report is not drawn with probe updates: refused with exit 2, not silently ignored."""
    folder, model = case
    code = main(["compare", str(model), str(folder / "later.csv"), "--probe-every", "2h",
                 "--report", str(folder / "r.html")])  # fmt: skip
    assert code == 2
    assert "--report" in capsys.readouterr().err
    assert not (folder / "r.html").exists()
