"""The report's time figures: graded failing windows for every model, the top candidate, aligned axes, unit panels."""

from __future__ import annotations

import pytest

from compd.files.data import load_data
from compd.files.modelfile import load_model
from compd.report import figures
from compd.report.gather import ReportData, gather
from compd.toolkit.evaluate import evaluate
from tests.report.conftest import DATA, REGRESSION, SEED000

OUTPUT = "disp_z_um"


@pytest.fixture(scope="module")
def compared() -> ReportData:
    """Horejs 2010's TF model against the controller's regression, the regression judged at 1 um."""
    data = load_data(str(DATA))
    return gather(
        evaluate(load_model(SEED000), data),
        other=evaluate(load_model(REGRESSION), data),
        tolerance_um=1.0,
    )


def _rects(fig: object) -> list:
    return [s for s in fig.layout.shapes if s.type == "rect"]  # type: ignore[attr-defined]


@pytest.mark.parametrize(
    ("rms_um", "grade"), [(1.2, 0), (1.5, 0), (1.7, 1), (3.0, 2), (7.0, 3), (10.5, 4), (80.0, 4)]
)
def test_windows_are_graded_by_how_far_they_exceed_the_limit(rms_um: float, grade: int) -> None:
    """A window 1–1.5x the limit is the lightest grade, one beyond 10x the darkest (limit 1 um)."""
    assert figures.window_grade(rms_um, 1.0) == grade


def test_every_models_failing_windows_are_shaded_in_its_own_panel(compared: ReportData) -> None:
    """Both models' failing windows are shaded, each in the panel of that model's residue, by grade."""
    fig = figures.residue(compared, OUTPUT)
    rects = _rects(fig)
    per_model = [r.outputs[OUTPUT].windows for r in compared.runs]
    assert all(result.windows for result in per_model), "the fixture makes both models fail"
    assert len(rects) == sum(len(result.windows) for result in per_model)
    for panel, result in zip(("x", "x2"), per_model, strict=True):
        shaded = [r for r in rects if r.xref == panel]
        assert len(shaded) == len(result.windows)
        for rect, window in zip(shaded, result.windows, strict=True):
            grade = figures.window_grade(window.rms_um, result.tolerance_um)
            assert rect.fillcolor == figures.WINDOW_GRADES[grade][2]
    assert len({r.fillcolor for r in rects}) >= 2, "windows of different excess look different"
    # one legend entry per grade shown
    labelled = [r.name for r in rects if r.showlegend]
    assert len(labelled) == len(set(labelled)) == len({r.fillcolor for r in rects})


def test_the_top_candidate_is_drawn_over_the_residue_in_its_unit(compared: ReportData) -> None:
    """Each residue panel carries the signal its diagnosis ranks first, on a second y axis titled with its unit."""
    fig = figures.residue(compared, OUTPUT)
    for row, run in enumerate(compared.runs, start=1):
        signal = figures.top_candidate(run, OUTPUT)
        assert signal is not None
        (trace,) = [
            t
            for t in fig.data
            if t.name == f"top candidate: {signal}" and t.yaxis in {f"y{2 * row}"}
        ]
        axis = fig.layout[f"yaxis{2 * row}"]
        assert axis.overlaying is not None and axis.side == "right"
        assert signal in axis.title.text
        if signal.endswith("_degC"):
            assert "(degC)" in axis.title.text
        assert len(trace.x) > 0


def test_every_time_axis_spans_the_record_with_the_same_margins(compared: ReportData) -> None:
    """Measured, residue, contributions and conditions share x range and side margins: they line up."""
    t = compared.data.time_s
    span = (t[0] / 3600.0, t[-1] / 3600.0)
    time_figures = [
        figures.measured_vs_simulated(compared, OUTPUT),
        figures.residue(compared, OUTPUT),
        *(figures.contributions(compared, r, OUTPUT) for r in compared.runs),
        figures.conditions(compared),
    ]
    for fig in time_figures:
        assert fig is not None
        assert (fig.layout.margin.l, fig.layout.margin.r) == (
            figures.TIME_MARGIN["l"],
            figures.TIME_MARGIN["r"],
        )
        axes = [fig.layout[k] for k in fig.layout if k.startswith("xaxis")]
        assert axes and all(tuple(a.range) == pytest.approx(span) for a in axes)


def test_operating_signals_are_drawn_in_a_panel_of_their_unit(compared: ReportData) -> None:
    """Each condition trace sits in the panel of its unit group, titled with that unit, with a legend of its own."""
    fig = figures.conditions(compared)
    assert fig is not None
    for row, group in enumerate(compared.conditions, start=1):
        axis = "y" if row == 1 else f"y{row}"
        drawn = [t.name for t in fig.data if t.yaxis == axis]
        assert tuple(drawn) == group.columns
        assert group.unit in fig.layout[f"yaxis{'' if row == 1 else row}"].title.text
        legend = "legend" if row == 1 else f"legend{row}"
        assert all(t.legend == legend for t in fig.data if t.yaxis == axis)
