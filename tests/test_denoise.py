"""``compd fit --denoise`` (Swiss-lathe paper): EMD offline, a matched low-pass, measured against the plain model."""

from __future__ import annotations

import numpy as np
import pytest

from compd.cli import main
from compd.files.data import load_data
from compd.files.modelfile import load_model
from compd.model.run import TickRunner
from compd.sim import simulate_scenario
from compd.sim.hall import air_conditioned
from compd.toolkit.denoise import remove_first_imfs
from compd.toolkit.evaluate import compare, evaluate, signal_matrix

TS = 10.0
INPUTS = "T_spindle_degC,T_ambient_degC"


def test_first_imf_removal_keeps_the_slow_signal():
    """Removing IMF1 from a slow swing plus a fast cycle leaves the slow swing, to 10 % of the fast amplitude."""
    k = np.arange(4000)
    slow = 20.0 + 1.5 * np.sin(2 * np.pi * k / 3000.0)
    fast = 0.4 * np.sin(2 * np.pi * k / 9.0)
    denoised = remove_first_imfs(slow + fast, 1)
    inner = slice(100, -100)  # EMD's spline envelopes are extrapolated at the ends
    assert np.sqrt(np.mean((denoised - slow)[inner] ** 2)) < 0.1 * 0.4 / np.sqrt(2)


@pytest.fixture(scope="module")
def twin_runs(tmp_path_factory):
    """A day of calibration and a day of a speed spectrum on the twin at 10 s, in an air-conditioned hall."""
    folder = tmp_path_factory.mktemp("denoise")
    paths = []
    for name, scenario, seed in (("calib", "calibration", 1), ("check", "speed_spectrum", 2)):
        frame = air_conditioned(simulate_scenario(scenario, 24.0, seed, TS), seed)
        path = folder / f"{name}.csv"
        frame.to_csv(path, index=False, float_format="%.9g")
        paths.append(path)
    return tuple(paths)


def _fit(calib, out, *extra):
    argv = ["fit", "--data", str(calib), "--output", "disp_z_um", "--inputs", INPUTS]
    return main([*argv, "--method", "arx", "--order", "2", "--out", str(out), *extra])


@pytest.fixture(scope="module")
def fitted(twin_runs, tmp_path_factory):
    """The plain ARX model and the one fitted with four EMD modes of the ambient sensor removed."""
    calib, _ = twin_runs
    folder = tmp_path_factory.mktemp("models")
    plain, denoised = folder / "plain.yaml", folder / "denoised.yaml"
    assert _fit(calib, plain) == 0
    assert _fit(calib, denoised, "--denoise", "T_ambient_degC", "--denoise-imfs", "4") == 0
    return load_model(plain), load_model(denoised)


def test_denoised_model_beats_the_plain_one_on_a_second_run(twin_runs, fitted):
    """On another day the file with the matched low-pass has a lower residue RMS and a higher fit than the plain one."""
    _, check = twin_runs
    data = load_data(check)
    plain, denoised = (compare(evaluate(m, data), "disp_z_um")[0] for m in fitted)
    assert denoised.residue.rms_um < plain.residue.rms_um
    assert denoised.fit_percent > plain.fit_percent


def test_provenance_records_the_denoising_and_its_cost(twin_runs, fitted):
    """Provenance names the input, modes, matched low-pass and both fits; compare reproduces the file's fit."""
    calib, _ = twin_runs
    _, model_file = fitted
    provenance = model_file.doc.provenance
    doc = provenance.denoise
    assert doc is not None and [i.input for i in doc.inputs] == ["T_ambient_degC"]
    (entry,) = doc.inputs
    assert entry.unit == "degC" and entry.imfs_removed == 4
    assert 10.0 <= entry.lowpass_tau_s <= 7200.0
    # The causal low-pass tracks the EMD result closer than the raw sensor does.
    assert 0.0 < entry.lowpass_vs_emd_rms < entry.raw_vs_emd_rms
    # The file's fit (raw sensor, low-pass inside) is what compare reproduces, and
    # causality costs little against the EMD-driven fit.
    (comparison,) = compare(evaluate(model_file, load_data(calib)))
    assert comparison.fit_percent == pytest.approx(provenance.fit_percent["disp_z_um"], abs=1e-6)
    assert doc.fit_percent_lowpass["disp_z_um"] == pytest.approx(comparison.fit_percent, abs=1e-6)
    assert abs(doc.fit_percent_emd["disp_z_um"] - comparison.fit_percent) < 1.0
    assert "EMD" in provenance.notes


def test_baked_file_runs_the_raw_sensor_through_the_low_pass(fitted):
    """The ambient sub-model's TF in the file has the low-pass's extra poles; the spindle one is unchanged."""
    plain, denoised = (m.model.outputs[0].submodels for m in fitted)
    stages = fitted[1].doc.provenance.denoise.inputs[0].lowpass_stages
    by_name = {sub.name: sub for sub in denoised}
    assert by_name["T_ambient_degC"].tf.order == plain[1].tf.order + stages
    assert by_name["T_spindle_degC"].tf.order == plain[0].tf.order


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (("--denoise", "T_bed_degC"), "not among the inputs"),
        (("--denoise", "T_ambient_degC", "--phase-gate", "spindle_speed_rpm"), "not supported"),
        (("--denoise", "T_ambient_degC", "--denoise-imfs", "0"), ">= 1"),
    ],
    ids=["not-an-input", "with-phase-gate", "zero-modes"],
)
def test_bad_denoise_exits_2_naming_the_option(twin_runs, tmp_path, capsys, extra, message):
    """A denoised column outside --inputs, with --phase-gate, or zero modes exits 2 naming --denoise."""
    calib, _ = twin_runs
    assert _fit(calib, tmp_path / "m.yaml", *extra) == 2
    err = capsys.readouterr().err
    assert message in err and "--denoise" in err


def test_a_signal_without_modes_is_returned_unchanged():
    """A monotonic ramp has no intrinsic mode to remove, so denoising leaves it as it is."""
    ramp = np.linspace(20.0, 22.0, 500)
    np.testing.assert_array_equal(remove_first_imfs(ramp, 2), ramp)


def test_more_modes_remove_the_ac_cycle_that_imf1_leaves():
    """On the hall's 10 s ambient sensor IMF1 holds only the noise; removing four modes removes the AC cycle too."""
    frame = simulate_scenario("calibration", 12.0, 7, TS)
    true_degC = frame["T_ambient_degC"].to_numpy()
    sensor_degC = air_conditioned(frame, 7)["T_ambient_degC"].to_numpy()
    inner = slice(50, -50)

    def rms_from_true(x):
        return np.sqrt(np.mean((x - true_degC)[inner] ** 2))

    one, four = (remove_first_imfs(sensor_degC, n) for n in (1, 4))
    assert rms_from_true(one) > 0.8 * rms_from_true(sensor_degC)  # the 0.4 degC cycle stays
    assert rms_from_true(four) < 0.5 * rms_from_true(sensor_degC)


def test_service_tick_runner_runs_the_denoised_file_unchanged(twin_runs, fitted):
    """Stepped one sample at a time as the service does, the denoised file gives compare's prediction."""
    _, check = twin_runs
    _, model_file = fitted
    data = load_data(check)
    evaluation = evaluate(model_file, data, init="rest")
    compiled = evaluation.compiled
    signals = signal_matrix(compiled, data)[:2000]
    runner = TickRunner(compiled, compiled.rest_state(signals[0]))
    stepped = np.array([runner.step(row)[0] for row in signals])
    np.testing.assert_allclose(stepped, evaluation.predicted("disp_z_um")[:2000], atol=1e-9)
