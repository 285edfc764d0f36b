"""Reports in a real headless browser (Debian chromium): they load cleanly and show every plot and number."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest

from compd.report.page import FIGURE_CLASS
from compd.report.tables import METRICS
from compd.toolkit.summary import fmt
from tests.report.conftest import Written
from tests.report_screenshot import chromium, chromium_missing, wait_for_plots

DIGITS = {key: digits for key, _, digits in METRICS}

pytestmark = pytest.mark.skipif(chromium_missing() is not None, reason=str(chromium_missing()))


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    """One headless chromium for the module (starting it is the expensive part)."""
    with chromium() as b:
        yield b


class Loaded:
    """A report as chromium shows it, with everything that went wrong while loading."""

    def __init__(self, browser: Any, written: Written) -> None:
        self.page = browser.new_page(viewport={"width": 1280, "height": 900})
        self.errors: list[str] = []
        self.requests: list[str] = []
        self.page.on("console", lambda m: self.errors.append(m.text) if m.type == "error" else None)
        self.page.on("pageerror", lambda e: self.errors.append(str(e)))
        self.page.on("request", lambda r: self.requests.append(r.url))
        self.page.goto(written.html_path.resolve().as_uri())
        self.n_figures = self.page.locator(f".{FIGURE_CLASS}").count()
        wait_for_plots(self.page, self.n_figures)

    def count(self, selector: str) -> int:
        return int(self.page.locator(selector).count())


def _no_errors_and_no_network(loaded: Loaded) -> None:
    """The page logs no console or script error and requests nothing beyond its own file."""
    assert loaded.errors == []
    assert all(url.startswith(("file:", "data:", "blob:")) for url in loaded.requests), (
        loaded.requests
    )


def _every_figure_draws_its_traces(loaded: Loaded) -> None:
    """Each figure has rendered SVG with at least one drawn trace (lines, areas or bars)."""
    assert loaded.n_figures >= 5
    ids = loaded.page.eval_on_selector_all(
        f".{FIGURE_CLASS} .js-plotly-plot", "nodes => nodes.map(n => n.id)"
    )
    assert len(ids) == loaded.n_figures
    for fig_id in ids:
        assert loaded.count(f"#{fig_id} .main-svg") >= 1, fig_id
        drawn = loaded.count(
            f"#{fig_id} .scatterlayer .trace path.js-line, #{fig_id} .scatterlayer .trace path.js-fill, "
            f"#{fig_id} .barlayer .trace .point"
        )
        assert drawn > 0, fig_id


def _numbers_equal_compare_json(loaded: Loaded, written: Written) -> None:
    """The embedded summaries and every visible metric cell equal ``compd compare --json``."""
    ids = ["compd-summary", "compd-summary-compare"][: len(written.summaries)]
    for element_id, expected in zip(ids, written.summaries, strict=True):
        embedded = loaded.page.evaluate(
            "id => JSON.parse(document.getElementById(id).textContent)", element_id
        )
        assert embedded == expected
    cells = loaded.page.eval_on_selector_all(
        "[data-key]",
        "nodes => nodes.map(n => [Number(n.dataset.model), n.dataset.output, n.dataset.key, "
        "n.innerText, n.offsetParent !== null])",
    )
    assert len(cells) == len(METRICS) * len(written.summaries)
    for model, output, key, text, visible in cells:
        assert visible, (model, key)
        assert text == fmt(written.summaries[model]["outputs"][output][key], DIGITS[key])


@pytest.mark.parametrize("fixture", ["single_report", "compare_report"])
def test_report_in_chromium(browser: Any, fixture: str, request: pytest.FixtureRequest) -> None:
    """A report loads in chromium without errors or network, draws every plot and shows compare --json's numbers.

    One page load per report (a load costs seconds of CPU): the checks are
    the helpers above, each a specification of its own.
    """
    written: Written = request.getfixturevalue(fixture)
    loaded = Loaded(browser, written)
    try:
        _no_errors_and_no_network(loaded)
        _every_figure_draws_its_traces(loaded)
        _numbers_equal_compare_json(loaded, written)
        output = next(iter(written.summaries[0]["outputs"]))
        n_models = len(written.summaries)
        # measured + one simulation per model; one residue per model
        assert loaded.count(f"#fig-{output}-measured .scatterlayer .trace") == 1 + n_models
        assert loaded.count(f"#fig-{output}-residue .scatterlayer .trace") == n_models
        failing = [w for w in written.summaries[0]["failing_windows"] if w["output"] == output]
        shaded = loaded.count(f"#fig-{output}-residue .layer-below .shapelayer path")
        assert shaded == len(failing)
    finally:
        loaded.page.close()
