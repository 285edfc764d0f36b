"""The hidden-effect loop over several runs: warm-up runs or days as separate files, each its own experiment.

A calibration of separate runs (record C of issue 20: five 6 h warm-up runs)
is fitted with ``compd fit --data runs/``; the hidden-effect loop takes the
same folder. The base model runs from its initial state at each file's
start, the new sub-model is judged leaving one file out at a time, and it
is the regularised lag bank over every file, its lags from rest at each
start. ``compd diagnose`` on the folder judges the effect it names the same
way, and ``compd report`` draws the runs end to end with compare's pooled
figures. Three cutting runs of 5 h (twin seeds 2-4) and an unseen fourth
(seed 5).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from compd.files.data import load_data
from compd.files.experiments import load_experiments, stack
from compd.files.modelfile import load_model
from compd.toolkit.evaluate import evaluate, evaluate_each
from tests.clirun import compd, compd_result
from tests.report.test_page import parse
from tests.workflow.test_hidden_effects import base_model, compd_json, fit_of, twin

RUN_HOURS = 5
OUTPUT = "disp_z_um"
SIGNAL = "spindle_power_kw"


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("extend-runs")


@pytest.fixture(scope="module")
def base(folder: Path) -> Path:
    return base_model(folder, twin(folder, "calibration", 24, seed=1), OUTPUT)


@pytest.fixture(scope="module")
def runs(folder: Path) -> Path:
    """Three cutting runs, one file each, in a folder of their own."""
    runs = folder / "runs"
    runs.mkdir()
    for seed in (2, 3, 4):
        twin(folder, "cutting", RUN_HOURS, seed).rename(runs / f"cutting-{seed}.csv")
    return runs


@pytest.fixture(scope="module")
def unseen(folder: Path) -> Path:
    return twin(folder, "cutting", RUN_HOURS, seed=5)


@pytest.fixture(scope="module")
def extended(folder: Path, base: Path, runs: Path) -> tuple[Path, dict]:
    out = folder / "extended.yaml"
    printed = compd("extend", base, runs, "--effect", SIGNAL, "--out", out, "--json")
    return out, json.loads(printed)


def test_the_effect_is_judged_one_run_out_at_a_time_and_added(
    extended: tuple[Path, dict],
) -> None:
    _, summary = extended
    held = summary["held_out"]
    assert held["folds"] == "leave one of 3 experiments (files) out"
    assert held["accepted"] and held["folds_improved"] == 3
    assert summary["method"] == "lagbank"
    assert summary["fit_percent_after"] > summary["fit_percent_before"] + 50


def test_the_extended_model_holds_on_an_unseen_run(
    extended: tuple[Path, dict], base: Path, unseen: Path, folder: Path, runs: Path
) -> None:
    """Better than the base model and at least as good as the extension on one run alone."""
    path, _ = extended
    one_run = folder / "extended-one-run.yaml"
    compd("extend", base, runs / "cutting-2.csv", "--effect", SIGNAL, "--out", one_run)
    fits = {
        name: fit_of(compd_json("compare", model, unseen), OUTPUT)
        for name, model in (("base", base), ("three runs", path), ("one run", one_run))
    }
    assert fits["base"] < 50.0
    assert fits["three runs"] >= 85.0
    assert fits["three runs"] >= fits["one run"] - 0.5, fits


def test_the_new_inputs_reference_is_the_runs_mean_start(
    extended: tuple[Path, dict], runs: Path
) -> None:
    """The thermal zero written for the daemon: the mean of the runs' first values, as ``fit`` sets it."""
    path, _ = extended
    firsts = [pd.read_csv(f)[SIGNAL].iloc[0] for f in sorted(runs.glob("*.csv"))]
    added = [
        s for o in load_model(path).model.outputs for s in o.submodels if s.input.signal == SIGNAL
    ]
    assert added
    for sub in added:
        assert sub.input.reference == pytest.approx(np.mean(firsts))


def test_a_second_extension_on_the_runs_refits_the_first_with_it(
    extended: tuple[Path, dict], runs: Path, folder: Path
) -> None:
    path, _ = extended
    again = folder / "again.yaml"
    summary = json.loads(
        compd("extend", path, runs, "--effect", "T_motor_degC", "--force", "--out", again, "--json")
    )
    assert summary["refitted"] == [SIGNAL]


def test_auto_takes_the_candidates_diagnose_finds_in_the_runs(
    base: Path, runs: Path, folder: Path
) -> None:
    summary = json.loads(
        compd("extend", base, runs, "--effect", "auto", "--out", folder / "auto.yaml", "--json")
    )
    assert summary["effect_signal"] == SIGNAL
    assert len(summary["tried"]) == 3


@pytest.mark.parametrize(
    ("option", "named"),
    [(("--method", "oe"), "--method oe"), (("--from", "1:00"), "--from")],
)
def test_what_works_on_one_record_only_is_refused_by_name(
    base: Path, runs: Path, folder: Path, option: tuple[str, str], named: str
) -> None:
    out = folder / "refused.yaml"
    code, _, err = compd_result("extend", base, runs, "--effect", SIGNAL, *option, "--out", out)
    assert code != 0
    assert named in err and "3 experiments" in err
    assert not out.exists()


def test_each_run_is_evaluated_from_its_own_start(base: Path, runs: Path) -> None:
    """The stacked evaluation is each file's own evaluation, end to end."""
    model = load_model(base)
    experiments = load_experiments([runs])
    stacked = evaluate_each(model, stack(experiments))
    assert stacked.starts == (0, len(experiments[0]), len(experiments[0]) + len(experiments[1]))
    alone = np.concatenate([evaluate(model, data).predicted(OUTPUT) for data in experiments])
    np.testing.assert_array_equal(stacked.predicted(OUTPUT), alone)
    one = load_data(runs / "cutting-2.csv")
    np.testing.assert_array_equal(
        evaluate_each(model, stack([one])).predicted(OUTPUT), evaluate(model, one).predicted(OUTPUT)
    )


@pytest.mark.parametrize("init", ["steady", "rest"])
def test_diagnose_over_the_runs_judges_the_named_effect_as_extend_on_them_does(
    extended: tuple[Path, dict], base: Path, runs: Path, init: str
) -> None:
    """Each file diagnosed alone names the effect; over all of them it is judged as ``extend`` judges it.

    ``extend`` runs the model from equilibrium at each start, so that judgement does too,
    whatever ``--init`` the per-file diagnosis takes.
    """
    _, summary = extended
    pooled = compd_json("diagnose", base, runs, "--init", init)["pooled"]
    assert pooled["missing_effects"] == {SIGNAL: 3}
    assert pooled["extended_over_files"][SIGNAL] == summary["held_out"]


def test_the_report_over_the_runs_is_what_compare_prints_pooled(
    extended: tuple[Path, dict], base: Path, runs: Path, folder: Path
) -> None:
    """The runs end to end, each from its own start; the figures are compare's, pooled and per file."""
    path, _ = extended
    out = folder / "runs.html"
    compd("report", path, runs, "--compare", base, "--out", out)
    html = out.read_text()
    scripts = parse(html).scripts
    for element_id, model in (("compd-summary", path), ("compd-summary-compare", base)):
        pooled = compd_json("compare", model, runs)["pooled"]["outputs"][OUTPUT]
        assert json.loads(scripts[element_id])["outputs"][OUTPUT]["fit_percent"] == (
            pytest.approx(pooled["fit_percent"], abs=1e-9)
        )
    assert "3 experiments (separate files or runs) end to end" in html
    assert "compd diagnose MODEL.yaml FILES" in html  # no candidates filtered across the files
    each = html[html.index('<table class="per-file">') :]
    rows = each[: each.index("</table>")].split("<tr>")[2:]
    experiments = compd_json("compare", path, runs)["experiments"]
    assert len(rows) == len(experiments) == 3
    for row, experiment in zip(rows, experiments, strict=True):
        assert f"<code>{experiment['data']}</code>" in row
        assert f"<td>{experiment['outputs'][OUTPUT]['fit_percent']:.1f}</td>" in row


def test_the_reports_windows_start_again_at_each_run(
    extended: tuple[Path, dict], runs: Path, folder: Path
) -> None:
    """No failing window straddles two runs: each run is judged in windows from its own start."""
    path, _ = extended
    out = folder / "windows.html"
    compd("report", path, runs, "--tolerance-um", "0.5", "--out", out)
    summary = json.loads(parse(out.read_text()).scripts["compd-summary"])
    firsts = np.cumsum([0, *(len(pd.read_csv(f)) for f in sorted(runs.glob("*.csv")))])[1:-1]
    run_starts_s = firsts * 10.0
    windows = summary["failing_windows"]
    assert windows
    for w in windows:
        assert not any(w["start_s"] < t < w["end_s"] for t in run_starts_s), w
    assert any(w["start_s"] == t for w in windows for t in run_starts_s)


def test_the_report_refuses_a_span_of_several_runs(
    extended: tuple[Path, dict], runs: Path, folder: Path
) -> None:
    path, _ = extended
    code, _, err = compd_result(
        "report", path, runs, "--until", "2:00", "--out", folder / "part.html"
    )
    assert code != 0 and "--until" in err and "3 experiments" in err


def test_verify_on_a_folder_of_unseen_runs_is_compares_pooled_figure(
    base: Path, runs: Path, unseen: Path, folder: Path
) -> None:
    later = folder / "later"
    later.mkdir()
    shutil.copy(unseen, later / "cutting-5.csv")
    shutil.copy(twin(folder, "cutting", RUN_HOURS, seed=6), later / "cutting-6.csv")
    out = folder / "verified.yaml"
    summary = json.loads(
        compd("extend", base, runs, "--effect", SIGNAL, "--verify", later, "--out", out, "--json")
    )
    for key, model in (("fit_percent_before", base), ("fit_percent_after", out)):
        pooled = compd_json("compare", model, later)["pooled"]["outputs"][OUTPUT]["fit_percent"]
        assert summary["verify"][key] == pytest.approx(pooled, abs=1e-9)
    assert summary["verify"]["fit_percent_after"] >= 85.0
