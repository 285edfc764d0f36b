"""Reports in a real headless browser (Debian chromium): they load cleanly and show every plot and number."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest

from compd.report import figures
from compd.report.page import FIGURE_CLASS
from compd.report.tables import METRICS
from compd.toolkit.summary import fmt
from tests.report.conftest import DATA, Written, cli_json
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
        # measured + one simulation per model; per model its residue and its top candidate
        assert loaded.count(f"#fig-{output}-measured .scatterlayer .trace") == 1 + n_models
        assert loaded.count(f"#fig-{output}-residue .scatterlayer .trace") == 2 * n_models
        _failing_windows_are_graded(loaded, written, output)
        _top_candidates_are_drawn_over_the_residue(loaded, written, output)
        _time_axes_line_up(loaded)
        _legends_clear_of_titles(loaded)
    finally:
        loaded.page.close()


def _failing_windows_are_graded(loaded: Loaded, written: Written, output: str) -> None:
    """Every model's failing windows are shaded in the residue figure, coloured by how far each exceeds the limit."""
    expected = []
    for summary in written.summaries:
        tolerance = summary["outputs"][output]["window_tolerance_um"]
        expected += [
            figures.WINDOW_GRADES[figures.window_grade(w["rms_um"], tolerance)][2]
            for w in summary["failing_windows"]
            if w["output"] == output
        ]
    assert expected, "the fixtures make windows fail"
    fills = loaded.page.evaluate(
        "id => document.getElementById(id).layout.shapes"
        ".filter(s => s.type === 'rect').map(s => s.fillcolor)",
        f"fig-{output}-residue",
    )
    assert fills == expected
    drawn = loaded.page.eval_on_selector_all(
        f"#fig-{output}-residue .shapelayer path",
        # closed paths: the windows' rectangles, not the dashed limit lines
        "nodes => nodes.filter(n => n.getAttribute('d').endsWith('Z'))"
        ".map(n => getComputedStyle(n).fill)",
    )
    assert len(drawn) == len(expected)
    assert len(set(drawn)) == len(set(expected))
    legend = loaded.page.eval_on_selector_all(
        f"#fig-{output}-residue .legendtext", "nodes => nodes.map(n => n.textContent)"
    )
    grades = {figures.WINDOW_GRADES[k][1] for k in range(len(figures.WINDOW_GRADES))}
    assert {t for t in legend if t in grades} == {
        label for _, label, colour in figures.WINDOW_GRADES if colour in expected
    }


def _top_candidates_are_drawn_over_the_residue(
    loaded: Loaded, written: Written, output: str
) -> None:
    """Each model's residue panel carries the signal ``compd diagnose`` ranks first, named in the legend."""
    residue_traces = loaded.page.evaluate(
        "id => document.getElementById(id).data.map(t => [t.name, t.yaxis])",
        f"fig-{output}-residue",
    )
    legend = loaded.page.eval_on_selector_all(
        f"#fig-{output}-residue .legendtext", "nodes => nodes.map(n => n.textContent)"
    )
    for row, model in enumerate(written.models, start=1):
        ranked = cli_json("diagnose", model, DATA, "--json")["candidates"]
        name = f"top candidate: {ranked[0]['signal']}"
        assert [name, f"y{2 * row}"] in residue_traces  # the panel's second y axis
        assert name in legend


def _time_axes_line_up(loaded: Loaded) -> None:
    """Every figure with a time axis draws it at the same left and right pixel edges."""
    edges = loaded.page.evaluate(
        """() => Array.from(document.querySelectorAll('.js-plotly-plot')).flatMap(gd => {
            const full = gd._fullLayout;
            const time = Object.keys(full).filter(k => /^xaxis\\d*$/.test(k))
                .map(k => full[k]).filter(ax => ((ax.title || {}).text || '').startsWith('time'));
            return time.map(ax => [gd.id, Math.round(ax._offset), Math.round(ax._length)]);
        })"""
    )
    assert len(edges) >= 4, edges
    assert len({(left, length) for _, left, length in edges}) == 1, edges


def _legends_clear_of_titles(loaded: Loaded) -> None:
    """No figure's legend overlaps its title, however many entries it wraps to."""
    boxes = loaded.page.evaluate(
        """() => Array.from(document.querySelectorAll('.js-plotly-plot')).flatMap(gd => {
            const title = gd.querySelector('.gtitle');
            if (!title) return [];
            const t = title.getBoundingClientRect();
            return Array.from(gd.querySelectorAll('.legend')).map(l => {
                const b = l.getBoundingClientRect();
                return [gd.id, [t.left, t.top, t.right, t.bottom], [b.left, b.top, b.right, b.bottom]];
            });
        })"""
    )
    assert boxes, "the figures have titles and legends"
    for fig_id, (tl, tt, tr, tb), (ll, lt, lr, lb) in boxes:
        overlap = min(tr, lr) > max(tl, ll) and min(tb, lb) > max(tt, lt)
        assert not overlap, (fig_id, (tl, tt, tr, tb), (ll, lt, lr, lb))
