"""A long record's report with `--compare` stays well under 2 MB: a point per pixel column, the template once."""

from __future__ import annotations

import base64
import json
import re

import numpy as np
import pytest

from compd.files.data import DataSet
from compd.files.modelfile import load_model
from compd.report.gather import gather
from compd.report.page import build_html
from compd.toolkit.evaluate import evaluate
from tests.report.conftest import GATED, day_record

#: plotly.js's basic bundle alone is 1.19 MB: what the figures may add to it for two models.
LIMIT_MB = 1.6


@pytest.fixture(scope="module")
def compared_day() -> tuple[str, DataSet]:
    """24 h at 1 Hz, the gated example beside itself: two models' lines, panels and contributions."""
    day = day_record()
    model = load_model(GATED)
    return build_html(gather(evaluate(model, day), other=evaluate(model, day))), day


def _traces(html: str) -> list[dict]:
    """Every trace of every figure, as the page hands them to plotly.js."""
    found = []
    for call in re.finditer(r'Plotly\.newPlot\(\s*"[^"]+",\s*', html):
        traces, _ = json.JSONDecoder().raw_decode(html, call.end())
        found += traces
    return found


def _points(trace: dict) -> int:
    x = trace.get("x")
    if isinstance(x, dict):  # a typed array: base64 of float32
        return len(np.frombuffer(base64.b64decode(x["bdata"]), dtype=x["dtype"]))
    return len(x or ())


def test_a_day_at_1hz_compared_gives_a_file_well_under_2_mb(compared_day: tuple[str, DataSet]):
    """Two models over 86,400 samples: the page is under 1.6 MB (plotly.js's bundle is 1.19 of it)."""
    html, _ = compared_day
    assert len(html.encode()) / 1e6 < LIMIT_MB


def test_every_line_draws_at_most_a_thousand_points(compared_day: tuple[str, DataSet]):
    """A line keeps a min and a max every two pixel columns: at most 1,000 points of the record's 86,400."""
    html, day = compared_day
    counts = [_points(t) for t in _traces(html) if t.get("mode") == "lines"]
    assert counts and max(counts) <= 1002 < len(day)
    stacked = [_points(t) for t in _traces(html) if t.get("stackgroup")]
    assert stacked and max(stacked) <= 502


def test_the_template_is_in_the_page_once_and_every_figure_uses_it(compared_day):
    """plotly's template (7 KB) is written once in the head; each figure's layout takes it from there."""
    html, _ = compared_day
    figures = len(re.findall(r"Plotly\.newPlot\(", html))
    assert html.count('"template":') == 0
    assert html.count("function compdTemplate()") == 1
    assert html.count("template:compdTemplate()") == figures
