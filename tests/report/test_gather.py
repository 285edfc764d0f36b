"""What a report shows, gathered from full-resolution data."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from numpy.testing import assert_allclose

from compd.files.data import DataSet, load_data
from compd.files.modelfile import load_model
from compd.report.figures import conditions
from compd.report.gather import ModelRun, ReportData, condition_groups, gather
from compd.report.page import build_html
from compd.toolkit.evaluate import Evaluation, evaluate
from tests.report.conftest import DATA, GATED, REGRESSION, SEED000, cli_json


@pytest.fixture(scope="module")
def data() -> DataSet:
    return load_data(str(DATA))


@pytest.fixture(scope="module")
def seed000(data: DataSet) -> Evaluation:
    return evaluate(load_model(SEED000), data)


@pytest.fixture(scope="module")
def compared(seed000: Evaluation, data: DataSet) -> ReportData:
    return gather(seed000, other=evaluate(load_model(REGRESSION), data))


def test_summary_is_what_compare_json_prints(compared: ReportData) -> None:
    """Each model's summary equals ``compd compare --json`` on the same files, key for key."""
    assert compared.primary.summary == cli_json("compare", SEED000, DATA, "--json")
    assert compared.other is not None
    assert compared.other.summary == cli_json("compare", REGRESSION, DATA, "--json")


def test_contributions_sum_to_the_simulated_output(compared: ReportData) -> None:
    """The stacked sub-model contributions of an output add up to that output's simulation (um)."""
    for run in compared.runs:
        parts = run.contributions("disp_z_um")
        assert_allclose(
            np.sum(list(parts.values()), axis=0), run.evaluation.predicted("disp_z_um"), atol=1e-9
        )
    assert list(compared.primary.contributions("disp_z_um")) == ["z_heat", "etve"]


def test_every_compared_output_has_windows_and_a_diagnosis(compared: ReportData) -> None:
    """Each compared output carries its failing-window result and its candidate ranking."""
    for run in compared.runs:
        analysis = run.outputs["disp_z_um"]
        assert analysis.windows.output == "disp_z_um"
        assert not isinstance(analysis.diagnosis, str)
        assert analysis.diagnosis.diagnosis.candidates


def test_other_model_without_the_output_is_noted(seed000: Evaluation, data: DataSet) -> None:
    """A compared model lacking an output the primary is compared on is shown for one model only, with a note."""
    report = gather(seed000, other=evaluate(load_model(GATED), data))
    assert report.other is not None and not report.other.outputs
    assert any("has no output ['disp_z_um']" in note for note in report.notes)


def test_conditions_are_grouped_by_unit(seed000: Evaluation) -> None:
    """Speed, power and temperatures get one axis each; displacements (um) are not conditions."""
    groups = condition_groups(seed000)
    assert [(g.unit, g.columns) for g in groups] == [
        ("rpm", ("spindle_speed_rpm",)),
        ("kW", ("spindle_power_kw",)),
        ("degC", ("T_spindle_degC", "T_ram_degC", "T_base_degC", "T_shopfloor_degC")),
    ]


def test_on_off_signals_share_one_axis(seed000: Evaluation) -> None:
    """Door and coolant columns holding only 0 and 1 are drawn together on an on/off axis."""
    data = seed000.data
    n = len(data)
    columns = dict(data.columns)
    columns["door_open"] = (np.arange(n) % 50 == 0).astype(float)
    columns["coolant_on"] = (np.arange(n) < n // 2).astype(float)
    columns["feed_x_mm_per_min"] = np.where(np.arange(n) % 7 == 0, 1200.0, 800.0)
    with_states = DataSet(data.path, data.time_s, data.sample_time_s, columns, None, ())
    groups = condition_groups(evaluate(seed000.model_file, with_states))
    units = {g.unit: g.columns for g in groups}
    assert units["0/1"] == ("door_open", "coolant_on")
    assert units["mm/min"] == ("feed_x_mm_per_min",)
    assert [g.unit for g in groups][:3] == ["rpm", "kW", "mm/min"]


def test_too_short_a_record_gives_a_reason_instead_of_a_ranking(seed000: Evaluation) -> None:
    """A record too short to cross-validate still gets windows and metrics; the ranking is replaced by why."""
    data = seed000.data
    k = 50  # 8 minutes at 10 s: fewer than the 64 a diagnosis needs
    short = DataSet(
        data.path,
        data.time_s[:k],
        data.sample_time_s,
        {n: v[:k] for n, v in data.columns.items()},
        None,
        (),
    )
    report = gather(evaluate(seed000.model_file, short))
    analysis = report.primary.outputs["disp_z_um"]
    assert isinstance(analysis.diagnosis, str) and "too few" in analysis.diagnosis
    assert analysis.windows.window_count == 1
    assert "no candidate ranking: " in build_html(report)


def test_unit_less_sensors_share_one_axis_and_constant_signals_get_none(
    seed000: Evaluation,
) -> None:
    """A real record's T1 .. T16 (no unit suffix) are one family on one axis; a constant column is not drawn."""
    data = seed000.data
    n = len(data)
    ramp = np.linspace(20.0, 25.0, n)
    columns = {f"T{i}": ramp + i for i in range(1, 17)}
    columns["chiller_state"] = np.full(n, 3.0)
    columns["spindle_speed_rpm"] = np.asarray(data.column("spindle_speed_rpm"))
    columns["disp_z_um"] = np.asarray(data.column("disp_z_um"))
    real = DataSet(data.path, data.time_s, data.sample_time_s, columns, None, ())
    groups = condition_groups(dataclasses.replace(seed000, data=real))
    assert [(g.label, g.columns) for g in groups] == [
        ("spindle speed", ("spindle_speed_rpm",)),
        ("T*", tuple(f"T{i}" for i in range(1, 17))),
    ]


_NAMES = st.from_regex(r"[A-Za-z][A-Za-z0-9_]{0,6}(_(rpm|kw|degC|bar|um|percent))?", fullmatch=True)


@settings(
    max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    names=st.lists(_NAMES, min_size=1, max_size=40, unique_by=str.lower), seed=st.integers(0, 99)
)
@example(names=[f"sensor{i}x" for i in range(30)], seed=1)  # 20 one-sensor families: 20 panels
def test_the_conditions_figure_is_drawn_for_any_columns(
    seed000: Evaluation, names: list[str], seed: int
) -> None:
    """Any valid record's columns, 1 to 40 of any name, give a conditions figure (or none), never an error."""
    data = seed000.data
    n = len(data)
    rng = np.random.default_rng(seed)
    columns = {
        name: rng.normal(20.0, 1.0, n) if i % 3 else np.zeros(n) for i, name in enumerate(names)
    }
    record = DataSet(data.path, data.time_s, data.sample_time_s, columns, None, ())
    evaluation = dataclasses.replace(seed000, data=record)
    groups = condition_groups(evaluation)
    figure = conditions(ReportData(ModelRun(evaluation, {}, {}), None, groups))
    assert (figure is None) == (not groups)
    drawn = [name for g in groups for name in g.columns]
    assert len(set(drawn)) == len(drawn)  # each column on one axis only
