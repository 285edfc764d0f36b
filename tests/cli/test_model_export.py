"""``compd model updates`` and ``compd model export --updated``: the daemon's probes, listed and written as a model."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from compd.cli import main
from compd.files.data import load_data
from compd.files.modelfile import load_model
from compd.files.probeprior import output_prior
from compd.files.probestate import ProbeRecord, append_record, learned_path, save_learned
from compd.model.metrics import fit_percent
from compd.model.probelearner import OutputLearner
from compd.model.proberegressors import output_columns
from compd.model.probesettings import ProbeSettings
from compd.model.run import TickRunner
from compd.report.verdict import fitted_on
from compd.toolkit.evaluate import evaluate
from tests.cli.test_compare_probes import _record

OUTPUT = "disp_z_um"
#: The daemon's clock: unix seconds, the record's first sample at this instant.
EPOCH_S = 1.75e9
#: The probes' steps at 2, 4, .., 10 h.
RESULTS = ["accepted", "accepted", "accepted", "flagged", "confirmed", "confirmed"]


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    """A model fitted on 24 h, run as the daemon runs it on 12 h of a machine heating 1.4x: probes every 2 h.

    Each probe arrives a minute after it touched; every step is logged and
    the learned state saved, as the daemon will. Returns the folder, the
    model, the state directory, the learner and the steps.
    """
    folder = tmp_path_factory.mktemp("export")
    _record(folder / "calib.csv", hours=24, heat_gain=1.0, seed=21)
    _record(folder / "later.csv", hours=12, heat_gain=1.4, seed=22)
    model = folder / "model.yaml"
    assert main(["fit", "--data", str(folder / "calib.csv"), "--output", OUTPUT,
                 "--inputs", "T_spindle_degC,T_ambient_degC", "--out", str(model)]) == 0  # fmt: skip
    model_file = load_model(model)
    run = evaluate(model_file, load_data(folder / "later.csv"))
    columns, names = output_columns(run.compiled, OUTPUT)
    prior = output_prior(model_file, OUTPUT, names).prior
    learner = OutputLearner(prior, ProbeSettings.defaults(prior))
    contributions = run.result.contributions[:, columns]
    x = prior.regressors(contributions)
    fixed = run.predicted(OUTPUT) - contributions.sum(axis=1)
    measured = run.data.column(OUTPUT)
    t_s = EPOCH_S + run.data.time_s
    touches = {k: k + 6 for k in range(720, len(t_s), 720)}  # every 2 h, read a minute later
    arrivals = {arrive: touch for touch, arrive in touches.items()}
    state = folder / "state"
    steps = []
    for k in range(len(t_s)):
        learner.observe(float(t_s[k]), x[k], float(fixed[k]))
        touch = arrivals.get(k)
        if touch is not None:
            taken = learner.probe(float(t_s[touch]), float(measured[touch]))
            for step in taken:
                record = ProbeRecord.of_step(
                    step, model_sha256=model_file.sha256, output=OUTPUT, source="plc", axis="z"
                )
                append_record(state, record)
            steps += taken
    save_learned(state, model_file.sha256, {OUTPUT: learner}, now_s=float(t_s[-1]))
    return folder, model, state, learner, steps, x, run


def test_the_exported_model_predicts_what_the_daemon_does_with_the_learned_parameters(
    served, capsys
) -> None:
    """Each sub-model at its learned coefficient, the bias as bias_um: the file's output is f + x' theta, to 1e-9 um."""
    folder, model, state, learner, steps, x, run = served
    # At 8 h the machine is 6.7 um off the model: flagged, taken when 10 h confirms it.
    assert [s.result for s in steps] == RESULTS
    out = folder / "updated.yaml"
    assert (
        main(["model", "export", "--updated", "--state-dir", str(state), str(model), str(out)]) == 0
    )
    printed = capsys.readouterr().out
    assert "5 probes since the last reset" in printed
    exported = evaluate(load_model(out), run.data)
    daemon = run.predicted(OUTPUT) + learner.adjustments_um(x)
    np.testing.assert_allclose(exported.predicted(OUTPUT), daemon, rtol=0, atol=1e-9)
    # compare judges the exported file as the daemon's adjusted output
    assert main(["compare", str(out), str(folder / "later.csv"), "--json"]) == 0
    judged = json.loads(capsys.readouterr().out)
    judged_fit = judged["outputs"][OUTPUT]["fit_percent"]
    assert judged_fit == pytest.approx(fit_percent(run.data.column(OUTPUT), daemon), abs=1e-6)
    assert judged_fit > fit_percent(run.data.column(OUTPUT), run.predicted(OUTPUT)) + 5.0
    bias = load_model(out).doc.outputs[OUTPUT].bias_um
    assert bias == pytest.approx(float(learner.theta[-1]), abs=1e-12) and bias != 0.0


def test_the_exported_file_passes_model_check_and_names_its_probes(served, capsys) -> None:
    """model check accepts it; its provenance names the parent and the five probes; its prior is the posterior."""
    folder, model, state, learner, steps, _, _ = served
    out = folder / "checked.yaml"
    assert (
        main(["model", "export", "--updated", "--state-dir", str(state), str(model), str(out)]) == 0
    )
    assert main(["model", "check", str(out)]) == 0
    assert "ok: compiles, causal and stable" in capsys.readouterr().out
    updated = load_model(out)
    (record,) = updated.doc.provenance.probe_updates
    assert record.parent_sha256 == load_model(model).sha256
    assert [p.result for p in record.probes] == RESULTS
    assert [p.innovation_before_um for p in record.probes] == [
        s.innovation_before_um for s in steps
    ]
    assert record.parameters[OUTPUT]["bias"] == pytest.approx(float(learner.theta[-1]), rel=1e-12)
    # The exported model starts from what was learned: its prior is the posterior, in the
    # learned coefficients (the new file's own).
    names = tuple(record.parameters[OUTPUT])[:-1]
    prior = output_prior(updated, OUTPUT, names)
    assert prior.note is None and prior.prior.form == "coefficients"
    assert prior.prior.coefficients is not None
    np.testing.assert_allclose(prior.prior.coefficients, learner.theta[:-1], rtol=1e-12)
    np.testing.assert_allclose(prior.prior.covariance, learner.updater.covariance, rtol=1e-8)


def test_a_file_bias_is_added_by_the_tick_runner_and_the_simulation_alike(served) -> None:
    """bias_um reaches the daemon's per-tick path (TickRunner) as it does compare's (simulate)."""
    folder, model, state, *_, run = served
    out = folder / "ticked.yaml"
    assert (
        main(["model", "export", "--updated", "--state-dir", str(state), str(model), str(out)]) == 0
    )
    exported = evaluate(load_model(out), run.data)
    compiled = exported.compiled
    first = {name: float(run.data.column(name)[0]) for name in compiled.signals}
    runner = TickRunner(compiled, compiled.steady_state(first))
    ticked = [
        runner.step({n: float(run.data.column(n)[k]) for n in compiled.signals})[0]
        for k in range(50)
    ]
    np.testing.assert_allclose(ticked, exported.predicted(OUTPUT)[:50], rtol=0, atol=1e-9)
    assert compiled.output_bias_um[0] != 0.0


def test_updates_lists_the_probes_and_their_innovations(served, capsys) -> None:
    """The probe log as a table and as JSON: every step, with its innovations before and after."""
    _, _, state, _, steps, _, _ = served
    assert main(["model", "updates", "--state-dir", str(state), "--json"]) == 0
    listed = json.loads(capsys.readouterr().out)["probes"]
    assert [p["result"] for p in listed] == RESULTS
    assert [p["innovation_after_um"] for p in listed] == [s.innovation_after_um for s in steps]
    assert {p["source"] for p in listed} == {"plc"}
    assert main(["model", "updates", "--state-dir", str(state)]) == 0
    table = capsys.readouterr().out
    assert "5 taken, 0 rejected or refused" in table
    assert f"{steps[0].innovation_before_um:+.2f}" in table


def test_export_without_updates_names_the_state_directory_and_the_fix(
    served, tmp_path, capsys
) -> None:
    """A model the daemon took no probe with: nothing written, the reason and the fix said."""
    _, model, _, _, _, _, _ = served
    out = tmp_path / "none.yaml"
    code = main(
        ["model", "export", "--updated", "--state-dir", str(tmp_path), str(model), str(out)]
    )
    assert code != 0 and not out.exists()
    err = capsys.readouterr().err
    assert "no probe updates of this model" in err and "--state-dir" in err
    assert str(learned_path(tmp_path, load_model(model).sha256).parent) in err


def test_the_provenance_names_only_the_probes_since_the_last_reset(served, tmp_path) -> None:
    """After a reset line in the log, the exported file names the probes logged after it, not before."""
    _, model, state, _, steps, _, _ = served
    copied = tmp_path / "state"
    shutil.copytree(state, copied)
    sha = load_model(model).sha256
    append_record(copied, ProbeRecord(EPOCH_S + 43_000, sha, OUTPUT, "socket", "reset"))
    later = ProbeRecord.of_step(steps[-1], model_sha256=sha, output=OUTPUT, source="cli")
    append_record(copied, later)
    out = tmp_path / "after-reset.yaml"
    assert (
        main(["model", "export", "--updated", "--state-dir", str(copied), str(model), str(out)])
        == 0
    )
    (record,) = load_model(out).doc.provenance.probe_updates
    assert [(p.source, p.result) for p in record.probes] == [("cli", RESULTS[-1])]


def test_a_file_exported_to_another_folder_still_names_the_record_it_was_fitted_on(
    served, tmp_path
) -> None:
    """Exported elsewhere, the provenance's paths are seen from the new folder: a report still knows the calibration."""
    folder, model, state, _, _, _, _ = served
    out = tmp_path / "elsewhere" / "updated.yaml"
    out.parent.mkdir()
    argv = ["model", "export", "--updated", "--state-dir", str(state), str(model), str(out)]
    assert main(argv) == 0
    assert fitted_on(load_model(out), str(folder / "calib.csv"))
