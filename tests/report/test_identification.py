"""What a System Identification Toolbox user looks for in a report: gains, step responses, residue test."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

from compd.cli import main
from compd.files.data import load_data
from compd.files.modelfile import load_model
from compd.model import stepresponse
from compd.model.lagbank import lag_tf
from compd.model.transfer import DiscreteTF
from compd.report import idfigures, modelcard
from compd.report.gather import ReportData, gather
from compd.report.inputs import input_responses
from compd.toolkit.evaluate import evaluate
from tests.report.conftest import DATA

INPUTS = ("T_spindle_degC", "T_ram_degC", "T_base_degC")
OUTPUT = "disp_z_um"


@pytest.fixture(scope="module")
def lagbank(tmp_path_factory: pytest.TempPathFactory) -> ReportData:
    """A lag bank fitted by ``compd fit`` on the bundled 8 h record, gathered for a report."""
    path = tmp_path_factory.mktemp("lagbank") / "lagbank.yaml"
    argv = ["fit", "--data", str(DATA), "--output", OUTPUT, "--inputs", ",".join(INPUTS)]
    assert main([*argv, "--method", "lagbank", "--out", str(path)]) == 0
    return gather(evaluate(load_model(path), load_data(str(DATA))))


def test_lag_bank_is_one_row_per_input(lagbank: ReportData) -> None:
    """The model card's per-input table has one row per lag-bank input; its dozen sub-models are folded."""
    card = modelcard.model_card(lagbank.primary, 0)
    inputs = card[
        card.index('class="inputs"') : card.index("</table>", card.index('class="inputs"'))
    ]
    assert inputs.count("<tr>") - 1 == len(INPUTS)
    for name in INPUTS:
        assert f'data-input="{name}"' in inputs
    n_submodels = lagbank.primary.evaluation.compiled.n_submodels
    assert n_submodels > 2 * len(INPUTS)
    assert f"<details><summary>all {n_submodels} sub-models</summary>" in card


def test_per_input_gain_is_the_sum_of_its_submodels_with_an_error(lagbank: ReportData) -> None:
    """Each input's static gain sums its sub-models' gain times B(1)/A(1), and carries a finite standard error."""
    compiled = lagbank.primary.evaluation.compiled
    for response in input_responses(lagbank.primary, OUTPUT):
        expected = sum(
            compiled.gain[i] * compiled.discrete[i].static_gain()
            for i, sub in enumerate(compiled.submodels)
            if sub.input.signal == response.label
        )
        assert_allclose(response.static_gain, expected, rtol=1e-12)
        assert 0.0 < response.standard_error < abs(response.static_gain)
        assert response.time_constants_s


def test_step_response_settles_at_the_static_gain(lagbank: ReportData) -> None:
    """The step-response figure's last value of each input equals that input's static gain (um per unit)."""
    fig = idfigures.step_responses(lagbank.primary, OUTPUT)
    assert fig is not None
    responses = input_responses(lagbank.primary, OUTPUT)
    assert len(fig.data) == len(responses)
    for trace, response in zip(fig.data, responses, strict=True):
        assert_allclose(trace.y[-1], response.static_gain, rtol=1e-3)
        assert re.search(
            rf"{response.static_gain:.3g} ± [0-9.e-]+ um per degC",
            "".join(a.text for a in fig.layout.annotations),
        )


def test_step_response_of_lags_is_their_analytic_sum() -> None:
    """Two first-order lags' step response is the sum of ``K (1 - exp(-t / tau))`` at the sample instants."""
    tfs: list[DiscreteTF] = [lag_tf(1.0, 600.0, 10.0), lag_tf(1.0, 3600.0, 10.0)]
    time_s, y = stepresponse.step_response(tfs, [2.0, -0.5], 10.0)
    expected = 2.0 * (1 - np.exp(-time_s / 600.0)) - 0.5 * (1 - np.exp(-time_s / 3600.0))
    assert_allclose(y, expected, atol=1e-9)
    assert_allclose(y[-1], stepresponse.static_gain(tfs, [2.0, -0.5]), rtol=1e-3)


def test_correlation_figure_carries_the_bounds(lagbank: ReportData) -> None:
    """The residue test draws each correlation inside a band of its 99 % Bartlett bound, one panel per signal."""
    panels = idfigures.correlation_panels(lagbank.primary, OUTPUT)
    assert panels[0].title == "residue autocorrelation"
    assert_allclose(panels[0].values[0], 1.0)
    titles = [p.title for p in panels[1:]]
    for name in INPUTS:
        assert f"residue × {name} (input leads)" in titles
    fig = idfigures.correlations(lagbank.primary, OUTPUT)
    assert fig is not None
    bands = [t for t in fig.data if t.name == "99 % bound"]
    assert len(bands) == len(panels)
    for band, panel in zip(bands, panels, strict=True):
        assert band.fill == "toself"
        upper = np.asarray(band.y[: len(band.y) // 2])
        assert np.all(upper > 0.0) and np.all(upper < 1.0)
        assert_allclose(upper.max(), np.nanmax(panel.bound), rtol=1e-6)


def test_report_page_has_step_and_correlation_figures(lagbank: ReportData, tmp_path: Path) -> None:
    """The written page holds one step-response and one residue-test figure per model and output."""
    from compd.report.page import build_html

    html = build_html(lagbank)
    assert f'id="fig-{OUTPUT}-steps-0"' in html
    assert f'id="fig-{OUTPUT}-correlations-0"' in html


def test_gain_errors_are_least_squares_errors_widened_for_the_residues_autocorrelation() -> None:
    """gain_check: the factor and its error are scipy's linregress slope and stderr, times sqrt((1+rho)/(1-rho))."""
    from scipy.stats import linregress

    rng = np.random.default_rng(3)
    n = 4000
    contribution = np.cumsum(rng.normal(size=n))
    noise = np.zeros(n)
    for k in range(1, n):  # an AR(1) residue, rho 0.8
        noise[k] = 0.8 * noise[k - 1] + rng.normal()
    measured = 1.1 * contribution + 2.0 + noise
    check = stepresponse.gain_check(contribution[:, None], measured)
    fit = linregress(contribution, measured)
    residue = measured - (fit.slope * contribution + fit.intercept)
    rho = float(residue[1:] @ residue[:-1] / (residue @ residue))
    assert_allclose(check.factors[0], fit.slope, rtol=1e-9)
    assert_allclose(check.lag1_autocorrelation, rho, rtol=1e-9)
    assert_allclose(check.widening, np.sqrt((1 + rho) / (1 - rho)), rtol=1e-9)
    assert_allclose(check.relative_errors[0], fit.stderr * check.widening, rtol=1e-9)
    assert_allclose(check.residue_rms, np.sqrt(np.mean(residue**2)), rtol=1e-9)
    assert 0.75 < rho < 0.85
