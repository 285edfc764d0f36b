"""A model's headline is the figure of the model its file holds, never another method's.

``compd fit --method oe`` writes an OE model; its cross-validation may keep
``mlr`` (the folds' best), and mlr's expected fit on new data is no figure of
the OE model. ``compd model check``, the report and the status page say so
rather than lead with it (:mod:`compd.files.modelfigures`).
"""

from __future__ import annotations

from pathlib import Path

from compd.cli import main
from compd.files.modelfigures import EXPECTED, figure_lines, fit_headline, model_figures
from compd.files.modelfile import load_model
from compd.files.modelschema import HeadlineDoc
from compd.files.yamlplace import resolve_path
from compd.service.config.loading import load_config
from compd.service.control.modelload import slot_from_bytes
from compd.service.http.server import _model_json

BUNDLED_OE = resolve_path("bundled:simulated_model.yaml", Path("."))
SIMULATED = resolve_path("bundled:simulated.yaml", Path("."))


def test_an_oe_model_whose_folds_kept_mlr_has_no_expected_figure_of_its_own() -> None:
    """The bundled OE model: no headline, and a plain line that the 91.3 % is mlr's, not this model's."""
    doc = load_model(BUNDLED_OE).doc
    assert doc.provenance.method == "oe" and doc.provenance.cross_validation is not None
    assert doc.provenance.cross_validation.kept == "mlr"
    figures = model_figures(doc)
    assert figures.headline is None
    (lead, rest), *_ = figure_lines(figures)
    assert lead.startswith(f"no {EXPECTED} for this oe model: its cross-validation kept mlr")
    assert "91.3 %" in lead and "not of the oe model this file holds" in lead
    assert "97.9 % on the data it was fitted on" in rest


def test_model_check_does_not_headline_another_method_s_figure(capsys) -> None:
    """compd model check on the bundled OE model never prints "expected fit on new data: 91.3 % (mlr"."""
    assert main(["model", "check", "bundled:simulated_model.yaml"]) == 0
    out = " ".join(capsys.readouterr().out.split())  # the terminal's wrapping undone
    assert f"{EXPECTED}: 91.3 %" not in out
    assert f"no {EXPECTED} for this oe model" in out


def test_the_status_page_shows_what_model_check_shows() -> None:
    """The page's "expected on new data" is this model's headline: none here, with the reason."""
    config = load_config(SIMULATED)
    slot = slot_from_bytes(config, BUNDLED_OE.read_bytes(), str(BUNDLED_OE), 0.0)
    shown = _model_json(slot)
    assert shown["held_out_fit_percent"] is None
    assert shown["held_out_note"] == model_figures(load_model(BUNDLED_OE).doc).not_judged()


def test_a_recorded_headline_of_another_method_is_not_credited() -> None:
    """A file that recorded the kept candidate's figure as its OE model's headline is read as having none."""
    doc = load_model(BUNDLED_OE).doc
    cv = doc.provenance.cross_validation
    assert cv is not None
    wrong = fit_headline(cv, doc.name)  # what compd fit recorded before it took the method
    assert wrong is not None and wrong.source.endswith(".mlr")
    recorded = doc.model_copy(
        update={"provenance": doc.provenance.model_copy(update={"headline": wrong})}
    )
    assert model_figures(recorded).headline is None


def test_the_figure_is_credited_where_the_folds_judged_the_file_s_method() -> None:
    """Folds that scored oe beside mlr give the OE model its own figure, named as oe's."""
    doc = load_model(BUNDLED_OE).doc
    cv = doc.provenance.cross_validation
    assert cv is not None
    judged = cv.model_copy(update={"fit_percent": {**cv.fit_percent, "oe": 95.0}})
    headline = fit_headline(judged, doc.name, "oe")
    assert isinstance(headline, HeadlineDoc)
    assert headline.percent == {"disp_z_um": 95.0} and headline.description.startswith("oe, ")
    assert headline.source == "cross_validation.fit_percent.oe"
    # The kept candidate's figure is credited to a model of the kept method, as before.
    own = fit_headline(cv, doc.name, "mlr")
    assert own is not None and own.source.endswith(".mlr")
