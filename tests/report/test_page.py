"""The report page without a browser: sections, self-containment, numbers, size."""

from __future__ import annotations

import json
import re
from html.parser import HTMLParser

import pytest

from compd.files.data import DataSet
from compd.files.modelfile import load_model
from compd.report.gather import gather
from compd.report.page import FIGURE_CLASS, build_html, json_script
from compd.report.tables import METRICS
from compd.toolkit.evaluate import evaluate
from compd.toolkit.summary import fmt
from tests.report.conftest import GATED, Written, day_record

DIGITS = {key: digits for key, _, digits in METRICS}


class _Cells(HTMLParser):
    """Collects the text of every ``<span data-key=...>`` and every JSON data block."""

    def __init__(self) -> None:
        super().__init__()
        self.cells: dict[tuple[int, str, str], str] = {}
        self.scripts: dict[str, str] = {}
        self._open: tuple[str, object] | None = None

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        a = dict(attrs)
        if tag == "span" and "data-key" in a:
            self._open = ("cell", (int(a["data-model"] or 0), a["data-output"], a["data-key"]))
        elif tag == "script" and a.get("type") == "application/json":
            self._open = ("json", a["id"])

    def handle_data(self, data: str) -> None:
        if self._open is None:
            return
        kind, key = self._open
        if kind == "cell":
            self.cells[key] = self.cells.get(key, "") + data  # type: ignore[index]
        else:
            self.scripts[key] = self.scripts.get(key, "") + data  # type: ignore[index]

    def handle_endtag(self, tag: str) -> None:
        if tag in ("span", "script"):
            self._open = None


def parse(html: str) -> _Cells:
    cells = _Cells()
    cells.feed(html)
    return cells


def test_single_report_has_every_section(single_report: Written) -> None:
    """A one-model report holds the model card, the output's metrics, four figures, windows, candidates, conditions."""
    html = single_report.html
    for marker in (
        'id="models"',
        'id="output-disp_y_um"',
        'class="metrics"',
        'id="fig-disp_y_um-measured"',
        'id="fig-disp_y_um-residue"',
        'id="fig-disp_y_um-contributions-0"',
        "Failing windows",
        "candidate ranking",
        'id="fig-conditions"',
        'id="compd-summary"',
    ):
        assert marker in html, marker


def test_report_is_self_contained(single_report: Written) -> None:
    """No script, stylesheet or image is fetched from the network: plotly.js is inlined exactly once."""
    html = single_report.html
    assert not re.search(
        r"""<(script|link|img|iframe)[^>]+(src|href)\s*=\s*["']?(https?:)?//""", html, re.I
    )
    assert not re.search(r"@import|url\(\s*['\"]?(https?:)?//", html, re.I)
    assert len(re.findall(r"\* plotly\.js (\(basic - minified\) )?v\d", html)) == 1
    # measured, residue, contributions, step responses, residue test, candidates, conditions
    assert html.count(f'class="{FIGURE_CLASS}"') == 7


def test_failing_windows_are_tabled(single_report: Written) -> None:
    """Each failing window of compare --json is one row of the windows table: span, RMS, times the limit."""
    failing = single_report.summaries[0]["failing_windows"]
    assert failing, "the fixture's 2.5 um limit makes some windows fail"
    html = single_report.html
    table = html[html.index('<table class="windows">') :]
    table = table[: table.index("</table>")]
    assert table.count("<tr>") == 1 + len(failing)
    tolerance = single_report.summaries[0]["outputs"][failing[0]["output"]]["window_tolerance_um"]
    for w in failing:
        assert f"<td>{w['rms_um']:.2f}</td>" in table
        assert f"{w['rms_um'] / tolerance:.1f}×</td>" in table  # how far over the limit


def test_embedded_summary_is_compare_json(single_report: Written, compare_report: Written) -> None:
    """The embedded summaries equal what ``compd compare --json`` prints for the same files."""
    for written, ids in (
        (single_report, ["compd-summary"]),
        (compare_report, ["compd-summary", "compd-summary-compare"]),
    ):
        scripts = parse(written.html).scripts
        for element_id, expected in zip(ids, written.summaries, strict=True):
            assert json.loads(scripts[element_id]) == expected


def test_metric_cells_show_compare_json_rounded(compare_report: Written) -> None:
    """Every visible metric cell is the compare --json value with compare's on-screen rounding."""
    cells = parse(compare_report.html).cells
    assert len(cells) == 2 * len(METRICS)
    for (model, output, key), text in cells.items():
        value = compare_report.summaries[model]["outputs"][output][key]
        assert text == fmt(value, DIGITS[key])


def test_compare_report_shows_change_between_models(compare_report: Written) -> None:
    """With --compare, fit % and residue RMS get a signed change column, coloured better or worse."""
    before, after = (s["outputs"]["disp_z_um"] for s in compare_report.summaries)
    html = compare_report.html
    fit_change = after["fit_percent"] - before["fit_percent"]
    rms_change = after["rms_um"] - before["rms_um"]
    assert f'<span class="worse">{fit_change:+.1f}</span>' in html  # the regression fits worse
    assert f'<span class="worse">{rms_change:+.2f}</span>' in html
    assert "change (2nd − 1st)" in html
    assert 'id="fig-disp_z_um-contributions-1"' in html


def test_provenance_calibration_and_extensions_are_shown(compare_report: Written) -> None:
    """A model's calibration data and fit, and each extension's fit before and after, are listed."""
    html = compare_report.html
    assert "calibration_run.csv" in html and "disp_z_um 65.2 %" in html
    assert "calibration ranges of 2 signals</summary>spindle_speed_rpm 0…3000" in html
    assert 'class="extensions"' in html
    assert "spindle_power_kw" in html and "disp_z_um 65.2 → 81.4" in html


def test_json_block_cannot_end_its_script() -> None:
    """``</script>`` or ``<!--`` inside a string value is escaped in the data block and parses back unchanged."""
    value = {"note": "</script><!-- <b>"}
    block = json_script("x", value)
    body = block.split(">", 1)[1].rsplit("</script>", 1)[0]
    assert "<" not in body
    assert json.loads(body) == value


@pytest.fixture(scope="module")
def day_at_1hz() -> DataSet:
    return day_record()


def test_day_long_record_gives_a_small_file(day_at_1hz: DataSet) -> None:
    """A 24 h record at 1 Hz gives a report under 2 MB: plotly.js's basic bundle, decimated lines.

    Its time is measured by benchmarks/bench_report.py, not here.
    """
    html = build_html(gather(evaluate(load_model(GATED), day_at_1hz)))
    size_mb = len(html.encode()) / 1e6
    assert 'class="candidates"' in html
    assert "plotly.js (basic - minified)" in html
    assert size_mb < 2.0, size_mb


def test_the_basic_bundle_draws_every_trace_the_report_uses(compare_report: Written) -> None:
    """Every trace type in the report is one the inlined basic bundle has, of plotly's plotly.js major version."""
    from plotly.offline import get_plotlyjs_version

    from compd.report.plotlyjs import BASIC_TRACES, basic_version

    html = compare_report.html
    used = set()
    for call in re.finditer(r'Plotly\.newPlot\(\s*"[^"]+",\s*', html):
        traces, _ = json.JSONDecoder().raw_decode(html, call.end())
        used |= {t.get("type", "scatter") for t in traces}
    assert used and used <= BASIC_TRACES
    assert basic_version().split(".")[0] == get_plotlyjs_version().split(".")[0]
