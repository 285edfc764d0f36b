"""The report page: one self-contained HTML file from gathered report data.

plotly.js (its basic partial bundle, :mod:`compd.report.plotlyjs`) is
inlined once in the page head (no CDN: the file opens on a shop-floor PC
without internet); each figure is a ``div`` with the script
that draws it. The ``compare --json`` object of each model is embedded as
``<script type="application/json" id="compd-summary">`` (and
``compd-summary-compare`` for ``--compare``) so scripts read the same numbers
the tables show. The page leads with what changed on the record
(:mod:`compd.report.verdict`); the models' ids, gains and provenance follow
the outputs.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from datetime import UTC, datetime
from functools import cache
from html import escape
from pathlib import Path
from string import Template

import plotly.graph_objects as go
import plotly.io as pio

from compd import __version__
from compd.report import figures, idfigures, tables
from compd.report.gather import ModelRun, ReportData, gather
from compd.report.modelcard import model_card
from compd.report.plotlyjs import plotly_js
from compd.report.verdict import verdict
from compd.toolkit.evaluate import Evaluation
from compd.toolkit.probecompare import ProbeRun
from compd.toolkit.summary import json_finite

#: CSS class of every figure's wrapper ``div`` (one per plot).
FIGURE_CLASS = "compd-figure"

_PLOT_CONFIG = {"displaylogo": False, "responsive": True, "toImageButtonOptions": {"scale": 2}}

_PAGE = Template("""<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<meta name="generator" content="compd $version">
<title>$title</title>
<style>
body { font-family: system-ui, -apple-system, "Segoe UI", Roboto, sans-serif; color: #222;
       max-width: 1200px; margin: 0 auto; padding: 0 1.2rem 3rem; line-height: 1.4; }
h1 { font-size: 1.5rem; margin: 1.2rem 0 0.3rem; }
h2 { font-size: 1.25rem; border-bottom: 2px solid #1f5fa8; padding-bottom: 0.2rem; margin-top: 2.2rem; }
h3 { font-size: 1.05rem; margin: 1.2rem 0 0.4rem; }
h4 { font-size: 0.95rem; margin: 0.8rem 0 0.3rem; }
table { border-collapse: collapse; margin: 0.4rem 0 1rem; font-size: 0.88rem; }
th, td { border: 1px solid #ddd; padding: 0.25rem 0.55rem; text-align: left; vertical-align: top; }
th { background: #f3f5f8; }
table.metrics td:not(:first-child) { text-align: right; font-variant-numeric: tabular-nums; }
table.metrics td:first-child { white-space: nowrap; }
.muted { color: #777; } .ok { color: #2a7d2a; } .verdict { font-weight: 600; }
p.lead { font-size: 1.1rem; margin: 0.5rem 0; }
.better { color: #2a7d2a; font-weight: 600; } .worse { color: #b3261e; font-weight: 600; }
.same { color: #777; }
.meta { color: #555; font-size: 0.92rem; }
.swatch { display: inline-block; width: 0.8em; height: 0.8em; margin-right: 0.4em; border-radius: 2px; }
.swatch.m0 { background: #1f5fa8; } .swatch.m1 { background: #d1495b; }
.compd-figure { margin: 0.6rem 0 0.4rem; }
nav a { margin-right: 1rem; }
code { font-size: 0.88em; }
</style>
<script type="text/javascript">$plotlyjs</script>
<script type="text/javascript">function compdTemplate() { return $template; }</script>
</head>
<body>
<header>
<h1>$title</h1>
<p class="meta">$meta</p>
<nav>$nav</nav>
</header>
<section id="verdict"><h2>What changed on this record</h2>
$verdict
</section>
$outputs
<section id="models"><h2>Model$plural</h2>
$models
</section>
<section id="conditions"><h2>Operating conditions</h2>
$conditions
</section>
$notes
<footer class="meta"><p>Written by compd $version on $created. Numbers are from the full-resolution
data; plotted lines keep each interval's minimum and maximum.</p></footer>
$summaries
</body>
</html>
""")


#: The template the figures are drawn with: in the page head once, as ``compdTemplate()`` (a
#: fresh object per figure), not in each figure's layout (7 KB each, a tenth of a long record's lines).
TEMPLATE = "plotly_white"


@cache
def _template() -> dict[str, object]:
    """:data:`TEMPLATE` as a figure's layout carries it (plotly's JSON of it)."""
    blank = json.loads(pio.to_json(go.Figure(layout={"template": TEMPLATE}), validate=False))
    template: dict[str, object] = blank["layout"]["template"]
    return template


def figure_html(fig: go.Figure, div_id: str) -> str:
    """One figure as a ``div`` plus its drawing script (plotly.js and the template in the page head).

    ``Plotly.newPlot(id, data, layout, config)`` as plotly's own ``to_html``
    writes it (numpy arrays as typed arrays), the layout's template, where it
    is :data:`TEMPLATE`, taken from the page's ``compdTemplate()``.
    """
    spec = json.loads(pio.to_json(fig, validate=False))
    layout = spec["layout"]
    shared = layout.get("template") == _template()
    if shared:
        del layout["template"]
    data_js, layout_js = (
        json.dumps(part, separators=(",", ":")).replace("</", "<\\/")
        for part in (spec["data"], layout)
    )
    if shared:
        layout_js = f"Object.assign({layout_js},{{template:compdTemplate()}})"
    height = f"{fig.layout.height}px" if fig.layout.height else "100%"
    return (
        f'<div class="{FIGURE_CLASS}"><div id="{div_id}" class="plotly-graph-div" '
        f'style="height:{height}; width:100%;"></div><script type="text/javascript">'
        f'Plotly.newPlot("{div_id}",{data_js},{layout_js},{json.dumps(_PLOT_CONFIG)});'
        "</script></div>"
    )


def json_script(element_id: str, value: object) -> str:
    """``value`` as an inline JSON data block; every ``<`` is escaped so no text can end the script."""
    text = json.dumps(json_finite(value), indent=1, allow_nan=False).replace("<", "\\u003c")
    return f'<script type="application/json" id="{element_id}">\n{text}\n</script>'


def build_html(report: ReportData) -> str:
    """The whole report page as one string."""
    data = report.data
    names = [r.name for r in report.runs]
    title = "compd report: " + " vs ".join(escape(n) for n in names)
    duration_h = data.time_s[-1] / 3600.0 if len(data) else 0.0
    start = f", starting {data.start_time.isoformat()}" if data.start_time else ""
    span = ""
    if len(data) and data.time_s[0] > 0.0:  # the scored part of a run (--from): say so
        duration_h -= data.time_s[0] / 3600.0
        span = (
            f", judged on {data.time_s[0] / 3600:.2f} h .. {data.time_s[-1] / 3600:.2f} h of the "
            "record, model run from the file's start"
        )
    starts = report.primary.evaluation.starts
    if len(starts) > 1:
        span = (
            f", {len(starts)} experiments (separate files or runs) end to end, the model run from "
            "its initial state at each one's start (dotted lines); every figure is pooled over "
            "them, as compd compare prints it"
        )
    meta = (
        f"data <code>{escape(data.path)}</code>: {len(data)} samples at {data.sample_time_s:g} s, "
        f"{duration_h:.2f} h{escape(start)}{span}"
    )
    nav = ['<a href="#verdict">what changed</a>']
    nav += [f'<a href="#output-{escape(o)}">{escape(o)}</a>' for o in report.primary.outputs]
    nav += ['<a href="#models">models</a>', '<a href="#conditions">operating conditions</a>']
    conditions = figures.conditions(report)
    notes = list(
        dict.fromkeys([*(n for r in report.runs for n in r.summary["notes"]), *report.notes])
    )
    summaries = [json_script("compd-summary", report.primary.summary)]
    if report.other is not None:
        summaries.append(json_script("compd-summary-compare", report.other.summary))
    return _PAGE.substitute(
        version=escape(__version__),
        title=title,
        plotlyjs=plotly_js(),
        template=json.dumps(_template(), separators=(",", ":")).replace("</", "<\\/"),
        meta=meta,
        nav="".join(nav),
        plural="s" if len(report.runs) > 1 else "",
        verdict=verdict(report),
        models="\n".join(model_card(r, i) for i, r in enumerate(report.runs)),
        outputs="\n".join(_output_section(report, o) for o in report.primary.outputs),
        conditions=(
            figure_html(conditions, "fig-conditions")
            if conditions is not None
            else '<p class="muted">The data file has no condition columns.</p>'
        ),
        notes=(
            '<section id="notes"><h2>Notes</h2><ul>'
            + "".join(f"<li>{escape(n)}</li>" for n in notes)
            + "</ul></section>"
            if notes
            else ""
        ),
        created=datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"),
        summaries="\n".join(summaries),
    )


def _output_section(report: ReportData, output: str) -> str:
    primary = report.primary.outputs[output]
    runs = [(i, r) for i, r in enumerate(report.runs) if output in r.outputs]
    parts = [
        f'<section class="output" id="output-{escape(output)}">',
        f'<h2>{escape(output)} <span class="meta">measured column '
        f"<code>{escape(primary.measured_column)}</code></span></h2>",
        tables.metrics_table(report, output),
        tables.per_file_table(report, output),
        figure_html(figures.measured_vs_simulated(report, output), f"fig-{output}-measured"),
        figure_html(figures.residue(report, output), f"fig-{output}-residue"),
        *_probe_parts(report, output),
        "<h3>Failing windows</h3>",
        *(tables.windows_table(r, output) for _, r in runs),
        "<h3>Sub-model contributions</h3>",
        *(
            figure_html(figures.contributions(report, r, output), f"fig-{output}-contributions-{i}")
            for i, r in runs
        ),
        "<h3>Step responses and static gains</h3>",
        *_figures(idfigures.step_responses, runs, output, "steps"),
        "<h3>Residue test: auto- and cross-correlation</h3>",
        *_figures(idfigures.correlations, runs, output, "correlations"),
        "<h3>What the residue still holds: candidate ranking</h3>",
    ]
    for i, run in runs:
        if len(runs) > 1:
            parts.append(f"<h4>{escape(run.name)}</h4>")
        bars = figures.candidates(run, output)
        if bars is not None:
            parts.append(figure_html(bars, f"fig-{output}-candidates-{i}"))
        parts.append(tables.candidates_table(run, output))
    parts.append("</section>")
    return "\n".join(parts)


def _probe_parts(report: ReportData, output: str) -> list[str]:
    """With probe updates: what they changed (open loop beside them), each probe, and the drawing."""
    run = report.probe_run(output)
    if run is None:
        return []
    return [
        f'<h3 id="probes-{escape(output)}">Probe updates: {escape(report.primary.name)}</h3>',
        tables.probes_table(run),
        figure_html(figures.probe_updates(report, run), f"fig-{output}-probes"),
        tables.probe_steps_table(run),
        json_script(f"compd-probes-{output}", run.as_dict()),
    ]


def _figures(
    draw: Callable[[ModelRun, str], go.Figure | None],
    runs: list[tuple[int, ModelRun]],
    output: str,
    kind: str,
) -> list[str]:
    """``draw``'s figure of each model, or a line saying there is none."""
    parts = []
    for i, run in runs:
        fig = draw(run, output)
        parts.append(
            figure_html(fig, f"fig-{output}-{kind}-{i}")
            if fig is not None
            else f'<p class="muted">{escape(run.name)}: none for {escape(output)}.</p>'
        )
    return parts


def write_report(
    path: str | Path,
    evaluation: Evaluation,
    *,
    other: Evaluation | None = None,
    column: str | None = None,
    tolerance_um: float | None = None,
    window_s: float = 900.0,
    probes: Sequence[ProbeRun] = (),
) -> Path:
    """Gather and write the report of ``evaluation`` (and ``other``, on the same data) to ``path``.

    ``probes``: ``evaluation``'s outputs with probe updates, each drawn in its output's section.
    """
    report = gather(
        evaluation,
        other=other,
        column=column,
        tolerance_um=tolerance_um,
        window_s=window_s,
        probes=probes,
    )
    path = Path(path)
    path.write_text(build_html(report), encoding="utf-8")
    return path
