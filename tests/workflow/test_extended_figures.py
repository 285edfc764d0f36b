"""Every figure an extended model's file stores and prints is that model's, or says it is its base model's.

The README's modelling loop on twin data (a calibration without cutting, a
cutting run to extend on, a second one to verify on): ``compd extend`` writes
the extended model's own figures, each equal to what ``compd compare`` gives
for that file on the same data; the figures ``compd fit`` recorded of the
base model move to ``provenance.base_model`` and are printed as the base
model's by ``compd model check`` and the report (issue 36, item 11).
"""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest

from compd.files.modelfigures import EXPECTED, HELD_OUT, VERIFIED, model_figures
from compd.files.modelfile import load_model
from compd.files.modelschema import ProvenanceDoc
from compd.files.modelwriter import model_to_yaml
from tests.clirun import compd

OUTPUT = "disp_z_um"
INPUTS = "T_spindle_degC,T_headstock_degC,T_column_front_degC,T_ambient_degC"


def compare(model: Path, data: Path) -> dict:
    """``compd compare MODEL DATA --json``'s figures of the output."""
    return json.loads(compd("compare", model, data, "--json"))["outputs"][OUTPUT]


def twin(folder: Path, scenario: str, hours: int, seed: int) -> Path:
    path = folder / f"{scenario}-{seed}.csv"
    compd(
        "twin", "--scenario", scenario, "--hours", hours, "--seed", seed,
        "--sample-time-s", 10, "--out", path,
    )  # fmt: skip
    return path


@pytest.fixture(scope="module")
def loop(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """calib, cutting, cutting2, base.yaml, cutting.yaml (with --verify) and held.yaml (without)."""
    folder = tmp_path_factory.mktemp("extended-figures")
    files = {
        "calib": twin(folder, "calibration", 24, seed=1),
        "cutting": twin(folder, "cutting", 16, seed=2),
        "cutting2": twin(folder, "cutting", 16, seed=3),
        "base": folder / "base.yaml",
        "extended": folder / "cutting.yaml",
        "held": folder / "held.yaml",
    }
    compd(
        "fit", "--data", files["calib"], "--output", OUTPUT, "--inputs", INPUTS,
        "--out", files["base"],
    )  # fmt: skip
    compd(
        "extend", files["base"], files["cutting"], "--effect", "spindle_power_kw",
        "--verify", files["cutting2"], "--out", files["extended"],
    )  # fmt: skip
    compd(
        "extend", files["base"], files["cutting"], "--effect", "spindle_power_kw",
        "--out", files["held"],
    )  # fmt: skip
    return files


def test_a_fitted_model_names_its_headline_figure_in_words(loop: dict[str, Path]) -> None:
    """compd fit's file leads with "expected fit on new data", the fold median it repeats named by key."""
    prov = load_model(loop["base"]).doc.provenance
    held_out = prov.cross_validation
    assert prov.headline is not None and held_out is not None
    assert prov.headline.name == EXPECTED
    assert prov.headline.model == load_model(loop["base"]).model.name
    assert prov.headline.percent == {OUTPUT: held_out.fold_median_percent[held_out.kept]}
    assert prov.headline.source == f"cross_validation.fold_median_percent.{held_out.kept}"
    assert "nested cross-validation" in prov.headline.description


def test_the_extended_models_headline_is_its_fit_on_the_verify_record_as_compare_gives_it(
    loop: dict[str, Path],
) -> None:
    """With --verify, the headline is the extended model's fit on that record: what compare prints."""
    extended = load_model(loop["extended"])
    headline = extended.doc.provenance.headline
    assert headline is not None and headline.name == VERIFIED
    assert headline.model == extended.model.name
    fit = compare(loop["extended"], loop["cutting2"])["fit_percent"]
    assert headline.percent[OUTPUT] == pytest.approx(fit, abs=1e-9)
    assert headline.source == "extensions[0].verify_fit_percent_after"


def test_its_fit_is_what_compare_gives_on_the_data_it_was_extended_on(
    loop: dict[str, Path],
) -> None:
    """provenance.fit_percent is the extended model's on the extension record, which fit_data names."""
    prov = load_model(loop["extended"]).doc.provenance
    assert prov.fit_data == loop["cutting"].name  # relative to the model's folder
    on_cutting = compare(loop["extended"], loop["cutting"])
    assert prov.fit_percent[OUTPUT] == pytest.approx(on_cutting["fit_percent"], abs=1e-9)
    # The failing-window tolerance's basis: the larger of the calibration's and its own there.
    assert prov.calibration is not None
    base_rms = load_model(loop["base"]).doc.provenance.calibration.rms_um[OUTPUT]  # type: ignore[union-attr]
    assert prov.calibration.rms_um[OUTPUT] == pytest.approx(
        max(base_rms, on_cutting["rms_um"]), abs=1e-9
    )
    assert prov.calibration.extended_with == [loop["cutting"].name]
    # It was not run over the calibration record: no calibration fit of it is claimed.
    assert OUTPUT not in prov.calibration.fit_percent


def test_the_base_models_figures_are_kept_as_the_base_models(loop: dict[str, Path]) -> None:
    """The fitted figures move to base_model with the base's name and sha256, equal to its own file's."""
    base, extended = load_model(loop["base"]), load_model(loop["extended"])
    prov = extended.doc.provenance
    assert prov.cross_validation is None
    moved = prov.base_model
    assert moved is not None
    assert (moved.name, moved.sha256) == (base.model.name, base.sha256)
    assert moved.headline == base.doc.provenance.headline
    assert moved.fit_percent == base.doc.provenance.fit_percent
    assert moved.cross_validation == base.doc.provenance.cross_validation
    assert "free-run simulation fit" in moved.notes and "free-run" not in prov.notes
    base_fit = compare(loop["base"], loop["calib"])["fit_percent"]
    assert moved.fit_percent[OUTPUT] == pytest.approx(base_fit, abs=1e-6)


def test_without_verify_the_headline_is_the_held_out_fit_extend_judged(
    loop: dict[str, Path],
) -> None:
    """Without --verify the extended model leads with its held-out fit on the extension record's folds."""
    prov = load_model(loop["held"]).doc.provenance
    assert prov.headline is not None and prov.headline.name == HELD_OUT
    (kept,) = [t for t in prov.extensions[-1].tried if t.kept]
    assert prov.headline.percent == {OUTPUT: kept.held_out_fit_percent_after}


def test_model_check_prints_the_extended_models_figures_and_names_the_base_models(
    loop: dict[str, Path],
) -> None:
    """model check: its fit on new data and on the extension record, then the base model's, named."""
    text = " ".join(compd("model", "check", loop["extended"]).split())
    on_new = compare(loop["extended"], loop["cutting2"])["fit_percent"]
    on_cutting = compare(loop["extended"], loop["cutting"])["fit_percent"]
    base = load_model(loop["base"])
    expected = base.doc.provenance.headline.percent[OUTPUT]  # type: ignore[union-attr]
    own = text.index(f"{VERIFIED}: {on_new:.1f} % ({loop['cutting2'].name}, a record not used")
    fitted = text.index(
        f"{on_cutting:.1f} % on {loop['cutting'].name}, the data it was extended on"
    )
    theirs = text.index(
        f"the base model {base.model.name} (sha256 {base.sha256[:12]}, before its extension): "
        f"{EXPECTED} {expected:.1f} %"
    )
    assert own < fitted < theirs < text.index("sub-model")


def test_an_extended_file_of_an_older_compd_loads_and_says_whose_its_figures_are(
    loop: dict[str, Path], tmp_path: Path
) -> None:
    """Written before base_model: the fitted figures beside the extensions are printed as the base's."""
    base, extended = load_model(loop["base"]), load_model(loop["extended"])
    moved = extended.doc.provenance.base_model
    assert moved is not None
    old = _older_extended_file(loop, tmp_path)
    figures = model_figures(load_model(old).doc)
    assert figures.headline is not None and figures.headline.name == VERIFIED
    assert figures.headline.percent == extended.doc.provenance.headline.percent  # type: ignore[union-attr]
    assert figures.base is not None and figures.base.fit_percent == moved.fit_percent
    assert figures.base_label == f"the base model (sha256 {base.sha256[:12]}, before its extension)"
    text = " ".join(compd("model", "check", old).split())
    own = text.index(f"{VERIFIED}: ")
    theirs = text.index(
        f"{figures.base_label}: {EXPECTED} {moved.headline.percent[OUTPUT]:.1f} %"  # type: ignore[union-attr]
    )
    assert own < theirs


def _older_extended_file(loop: dict[str, Path], folder: Path) -> Path:
    """The extended model as compd wrote it before base_model: the fitted figures at the top."""
    extended = load_model(loop["extended"])
    moved = extended.doc.provenance.base_model
    assert moved is not None and extended.doc.provenance.calibration is not None
    calibration = extended.doc.provenance.calibration.model_copy(
        update={"fit_percent": moved.fit_percent, "extended_with": []}
    )
    older = ProvenanceDoc.model_validate(
        {
            **extended.doc.provenance.model_dump(exclude={"headline", "base_model", "fit_data"}),
            "fit_percent": moved.fit_percent,
            "cross_validation": moved.cross_validation,
            "calibration": calibration,
            "notes": moved.notes,
        }
    )
    old = folder / "old.yaml"
    old.write_text(
        model_to_yaml(
            extended.model,
            description=extended.doc.description,
            signals=extended.signal_units(),
            provenance=older,
        )
    )
    return old


def test_the_report_leads_with_the_change_and_each_model_with_its_own_figure(
    loop: dict[str, Path], tmp_path: Path
) -> None:
    """The report opens with fit before -> after on its record; each card's bold figure is its own."""
    page = tmp_path / "report.html"
    compd("report", loop["base"], loop["cutting2"], "--compare", loop["extended"], "--out", page)
    html = page.read_text()
    before = compare(loop["base"], loop["cutting2"])
    after = compare(loop["extended"], loop["cutting2"])
    lead = (
        f"<b>{OUTPUT}: fit {before['fit_percent']:.1f} % → {after['fit_percent']:.1f} % "
        f"({after['fit_percent'] - before['fit_percent']:+.1f} points)</b>"
    )
    assert lead in html
    assert html.index(lead) < html.index(f'id="output-{OUTPUT}"') < html.index('id="models"')
    base_card, extended_card = html.split('<div class="model">')[1:3]
    expected = load_model(loop["base"]).doc.provenance.headline.percent[OUTPUT]  # type: ignore[union-attr]
    assert f"<b>{EXPECTED}: {expected:.1f} %</b>" in base_card
    assert f"<b>{VERIFIED}: {after['fit_percent']:.1f} %</b>" in extended_card
    assert f"<b>{EXPECTED}" not in extended_card  # the base's figure is there, not in bold
    assert f"the base model {load_model(loop['base']).model.name}" in extended_card


def test_the_same_gains_errors_differ_by_what_the_record_leaves_and_the_report_says_why(
    loop: dict[str, Path],
) -> None:
    """On the cutting record the base model's errors are the missing effect's drift, not its gains' (item 13)."""
    from compd.files.data import load_data
    from compd.report.gather import gather
    from compd.report.inputs import inputs_and_check
    from compd.report.modelcard import DRIFT_AUTOCORRELATION, model_card
    from compd.toolkit.evaluate import evaluate

    data = load_data(loop["cutting2"])
    report = gather(evaluate(load_model(loop["base"]), data))
    other = gather(evaluate(load_model(loop["extended"]), data))
    (base_inputs, base_check), (ext_inputs, ext_check) = (
        inputs_and_check(r.primary, OUTPUT) for r in (report, other)
    )
    assert base_check is not None and ext_check is not None
    for mine, theirs in zip(base_inputs, ext_inputs, strict=False):  # the base's four inputs
        assert mine.label == theirs.label
        assert mine.static_gain == pytest.approx(theirs.static_gain, rel=1e-12)  # the same gains
        assert mine.standard_error > 10 * theirs.standard_error
    # Why: the base model leaves the cutting heat's drift, a slow residue, not noise.
    assert base_check.lag1_autocorrelation >= DRIFT_AUTOCORRELATION > ext_check.lag1_autocorrelation
    assert base_check.residue_rms > 5 * ext_check.residue_rms
    assert "A residue this slow is a drift" in model_card(report.primary, 0)
    assert "A residue this slow is a drift" not in model_card(other.primary, 1)


def test_a_report_on_the_record_a_model_was_fitted_on_says_so_first(
    loop: dict[str, Path], tmp_path: Path
) -> None:
    """One model on its own calibration: the lead gives its figures there and says they are in-sample."""
    page = tmp_path / "own.html"
    compd("report", loop["base"], loop["calib"], "--out", page)
    html = page.read_text()
    figures = compare(loop["base"], loop["calib"])
    lead = f"<b>{OUTPUT}: fit {figures['fit_percent']:.1f} %</b>, residue RMS {figures['rms_um']:.2f} um"
    assert lead in html and html.index(lead) < html.index('id="models"')
    assert "was fitted on <code>" in html and "not on new data" in html
    # and on a record it was not fitted on, no such line
    compd("report", loop["base"], loop["cutting"], "--out", page)
    assert "not on new data" not in page.read_text()


def test_the_report_of_an_older_extended_file_names_the_base_models_figures(
    loop: dict[str, Path], tmp_path: Path
) -> None:
    """The report card of an extended file of an older compd gives its calibration fit and notes as the base's."""
    from compd.files.data import load_data
    from compd.report.gather import gather
    from compd.report.modelcard import model_card
    from compd.toolkit.evaluate import evaluate

    old = _older_extended_file(loop, tmp_path)
    card = model_card(gather(evaluate(load_model(old), load_data(loop["cutting2"]))).primary, 0)
    label = model_figures(load_model(old).doc).base_label
    assert f"fit of {label} " in card
    assert f"<li>notes of {label}: free-run simulation fit" in card
    assert "<li>notes: " not in card


def test_a_record_not_zeroed_widens_the_calibration_by_its_change_and_says_so(
    loop: dict[str, Path], tmp_path: Path
) -> None:
    """Extended on a run whose displacement starts at 500 um, the output's calibrated range (the daemon's
    envelope) widens by the run's change from its start, not to 500 um, and extend says it zeroed it."""
    raised = tmp_path / "raised.csv"
    frame = pd.read_csv(loop["cutting"])
    frame[OUTPUT] += 500.0
    frame.to_csv(raised, index=False)
    out = tmp_path / "raised.yaml"
    summary = json.loads(
        compd(
            "extend", loop["base"], raised, "--effect", "spindle_power_kw", "--out", out, "--json"
        )
    )
    low, high = load_model(out).output_range(OUTPUT) or (0.0, 0.0)
    base_low, _ = load_model(loop["base"]).output_range(OUTPUT) or (0.0, 0.0)
    assert low == base_low and high < 1.0  # the run's own change from its start, not 500 um
    assert any("disp_z_um starts at 500" in note for note in summary["notes"]), summary["notes"]
