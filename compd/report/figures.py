"""The report's plots, drawn with plotly from gathered data.

Lines are drawn from min/max-decimated samples (see ``decimate``) so a long
record stays light in the browser; every number printed beside a plot comes
from the full-resolution data in ``gather``. Traces are SVG (``go.Scatter``,
not WebGL): they render on any shop-floor PC, GPU or not.
"""

from __future__ import annotations

import numpy as np
import plotly.graph_objects as go
from plotly.subplots import make_subplots

from compd.report import analysis_view as view
from compd.report.decimate import DEFAULT_BUCKETS, minmax_indices
from compd.report.gather import ModelRun, ReportData, column_unit, declared_units
from compd.toolkit.probecompare import ProbeRun

#: One colour per model (primary, compared), the measurement in black.
MODEL_COLOURS = ("#1f5fa8", "#d1495b")
MEASURED_COLOUR = "#222222"
#: The top-ranked candidate signal drawn over the residue (on a second y axis).
CANDIDATE_COLOUR = "#2a9d8f"
#: Failing windows shaded by how far their residue RMS exceeds the limit:
#: (ratio above which the grade starts, legend label, fill colour). A reader
#: sees at a glance the few windows far beyond the limit among many just over it.
WINDOW_GRADES = (
    (1.0, "window RMS 1–1.5× limit", "rgba(252, 187, 161, 0.45)"),
    (1.5, "1.5–2×", "rgba(252, 146, 114, 0.45)"),
    (2.0, "2–5×", "rgba(251, 106, 74, 0.45)"),
    (5.0, "5–10×", "rgba(222, 45, 38, 0.45)"),
    (10.0, "> 10×", "rgba(165, 15, 21, 0.5)"),
)
#: Margins of every figure on the time axis, so their plot areas line up one
#: above the other (the right one leaves room for the residue's second axis).
TIME_MARGIN = {"l": 80, "r": 90, "t": 60, "b": 50}
_HEIGHT_PX = 340


def time_h(report: ReportData) -> np.ndarray:
    """The record's time axis in hours, as drawn (float32: see :func:`drawn`)."""
    return drawn(np.asarray(report.data.time_s) / 3600.0)


def drawn(values: np.ndarray) -> np.ndarray:
    """Values as sent to the browser: float32 halves the file and is exact to the pixel."""
    return np.asarray(values, dtype=np.float32)


def _layout(fig: go.Figure, title: str, y_title: str, *, height: int = _HEIGHT_PX) -> go.Figure:
    fig.update_layout(
        title={"text": title, "x": 0.0, "xanchor": "left", "font": {"size": 15}},
        template="plotly_white",
        height=height,
        margin={"l": 70, "r": 20, "t": 60, "b": 50},
        legend={"orientation": "h", "yanchor": "bottom", "y": 1.0, "xanchor": "right", "x": 1.0},
        hovermode="x unified",
    )
    fig.update_xaxes(title_text="time (h)")
    fig.update_yaxes(title_text=y_title)
    return fig


def legend_under_title(fig: go.Figure, width_px: float = 1000.0) -> go.Figure:
    """The title at the very top, the legend left-aligned under it, the plot below both.

    The top margin grows with the legend rows the entries' names need at
    ``width_px`` (plotly wraps a horizontal legend at the plot's width), so a
    long legend pushes the plot down instead of running into the title.
    """
    names = [t.name or "" for t in fig.data if t.showlegend is not False]
    entries_px = [45.0 + 7.5 * len(n) for n in names]
    rows, used = 1, 0.0
    for px in entries_px:
        if used and used + px > width_px:
            rows, used = rows + 1, 0.0
        used += px
    fig.update_layout(
        title={"yref": "container", "y": 0.99, "yanchor": "top"},
        legend={"orientation": "h", "y": 1.02, "yanchor": "bottom", "x": 0.0, "xanchor": "left"},
        margin={"t": 40 + 24 * rows},
    )
    return fig


def _time_axis(fig: go.Figure, report: ReportData) -> go.Figure:
    """The record's whole span on every x axis and :data:`TIME_MARGIN`: time axes align across figures."""
    t = report.data.time_s
    fig.update_xaxes(range=[float(t[0]) / 3600.0, float(t[-1]) / 3600.0])
    fig.update_layout(margin=TIME_MARGIN)
    for start in report.primary.evaluation.starts[1:]:  # several files end to end
        fig.add_vline(x=float(t[start]) / 3600.0, line={"dash": "dot", "color": "#888", "width": 1})
    return fig


def window_grade(rms_um: float, tolerance_um: float) -> int:
    """Index into :data:`WINDOW_GRADES` of a failing window: how far its RMS exceeds the limit."""
    ratio = rms_um / tolerance_um
    return max(k for k, (low, _, _) in enumerate(WINDOW_GRADES) if ratio > low or k == 0)


def _line(
    x: np.ndarray, y: np.ndarray, index: np.ndarray, name: str, colour: str, **kwargs: object
) -> go.Scatter:
    return go.Scatter(
        x=x[index],
        y=drawn(y[index]),
        name=name,
        mode="lines",
        line={"color": colour, "width": 1.4},
        hovertemplate="%{y:.2f} um",
        **kwargs,
    )


def measured_vs_simulated(report: ReportData, output: str) -> go.Figure:
    """The measured displacement and each model's free-run simulation of it, in um."""
    x = time_h(report)
    runs = [r for r in report.runs if output in r.outputs]
    column = runs[0].outputs[output].measured_column
    measured = report.data.column(column)
    fig = go.Figure()
    fig.add_trace(_line(x, measured, _kept(measured), f"measured ({column})", MEASURED_COLOUR))
    for i, run in enumerate(runs):
        y = run.evaluation.predicted(output)
        fig.add_trace(_line(x, y, _kept(y), f"simulated: {run.name}", MODEL_COLOURS[i]))
    fig = _layout(fig, f"{output}: measured vs simulated (free run)", "displacement (um)")
    return legend_under_title(_time_axis(fig, report))


#: The prediction with probe updates, and the probes by result.
PROBED_COLOUR = "#2e7d32"
PROBE_RESULT_COLOURS = {
    "accepted": "#2e7d32",
    "confirmed": "#1b5e20",
    "flagged": "#f9a825",
    "rejected": "#c62828",
}


def probe_updates(report: ReportData, run: ProbeRun) -> go.Figure:
    """Measured, the model open loop and with probe updates, and each probe at its instant."""
    x = time_h(report)
    output = run.output
    column = report.primary.outputs[output].measured_column
    measured = report.data.column(column)
    open_loop = report.primary.evaluation.predicted(output)
    fig = go.Figure()
    fig.add_trace(_line(x, measured, _kept(measured), f"measured ({column})", MEASURED_COLOUR))
    fig.add_trace(_line(x, open_loop, _kept(open_loop), "open loop", MODEL_COLOURS[0]))
    fig.add_trace(
        _line(x, run.predicted_um, _kept(run.predicted_um), "with probe updates", PROBED_COLOUR)
    )
    for result, colour in PROBE_RESULT_COLOURS.items():
        steps = [s for s in run.steps if s.result == result]
        if not steps:
            continue
        fig.add_trace(
            go.Scatter(
                x=drawn(np.array([s.time_s for s in steps]) / 3600.0),
                y=drawn(np.array([s.measured_um for s in steps])),
                name=f"probe {result}",
                mode="markers",
                marker={"color": colour, "size": 9, "symbol": "diamond"},
                customdata=np.array(
                    [[s.innovation_before_um, s.innovation_after_um] for s in steps]
                ),
                hovertemplate=(
                    "%{y:.2f} um, innovation %{customdata[0]:+.2f} um, after the update "
                    "%{customdata[1]:+.2f} um"
                ),
            )
        )
    title = (
        f"{output}: probe updates ({run.probe_count} probes), fit "
        f"{run.open_loop.fit_percent:.1f} % open loop, {run.with_probes.fit_percent:.1f} % with them"
    )
    fig = _layout(fig, title, "displacement (um)")
    return legend_under_title(_time_axis(fig, report))


def _kept(y: np.ndarray) -> np.ndarray:
    """Samples of one line to draw (each line on its own: unstacked lines need no common x)."""
    return minmax_indices([y], DEFAULT_BUCKETS)


def residue(report: ReportData, output: str) -> go.Figure:
    """Each model's residue (um) in a panel of its own, sharing the time axis.

    In each panel: the failing windows of that model shaded by grade
    (:data:`WINDOW_GRADES`), its RMS limit ±tolerance dashed, and the
    candidate signal its diagnosis ranks first drawn on a second y axis in
    the signal's unit, so a reader sees whether the residue follows it.
    """
    x = time_h(report)
    runs = [(i, r) for i, r in enumerate(report.runs) if output in r.outputs]
    measured = report.data.column(runs[0][1].outputs[output].measured_column)
    fig = make_subplots(
        rows=len(runs),
        cols=1,
        shared_xaxes=True,
        vertical_spacing=0.1,
        specs=[[{"secondary_y": True}] for _ in runs],
        subplot_titles=[_residue_title(run, output) for _, run in runs],
    )
    fig = _layout(fig, f"{output}: residue (measured − simulated)", "")
    graded: set[int] = set()
    for row, (i, run) in enumerate(runs, start=1):
        y = measured - run.evaluation.predicted(output)
        fig.add_trace(
            _line(x, y, _kept(y), f"residue: {run.name}", MODEL_COLOURS[i]), row=row, col=1
        )
        result = run.outputs[output].windows
        tolerance = view.tolerance_um(result)
        for sign in (1.0, -1.0):
            fig.add_hline(
                y=sign * tolerance,
                line={"color": "#888888", "dash": "dash", "width": 1},
                row=row,
                col=1,
            )
        for window in view.windows(result):
            grade = window_grade(window.rms_um, tolerance)
            _, label, colour = WINDOW_GRADES[grade]
            fig.add_vrect(
                x0=window.start_s / 3600.0,
                x1=window.end_s / 3600.0,
                fillcolor=colour,
                line_width=0,
                layer="below",
                name=label,
                legendgroup=f"grade{grade}",
                legendrank=1000 + grade,  # grades in order, after the lines
                showlegend=grade not in graded,
                row=row,
                col=1,
            )
            graded.add(grade)
        fig.update_yaxes(title_text="residue (um)", row=row, col=1, secondary_y=False)
        _overlay_candidate(fig, report, run, output, row)
    fig.update_layout(
        height=_HEIGHT_PX + 60 + 260 * (len(runs) - 1),
        legend={"y": 1.04, "x": 0.0, "xanchor": "left"},  # under the title, however long
    )
    fig.update_xaxes(title_text="")
    fig.update_xaxes(title_text="time (h)", row=len(runs), col=1)
    for annotation in fig.layout.annotations:  # subplot titles: left, as the figure's
        annotation.update(x=0.0, xanchor="left", font={"size": 13})
    # make_subplots narrows the plot for the second y axis; its ticks and
    # title go in the right margin instead, so this plot lines up with the rest.
    fig.update_xaxes(domain=[0.0, 1.0])
    fig = _time_axis(fig, report)
    # the title at the very top, two rows of legend between it and the plot
    fig.update_layout(margin={"t": 110}, title={"yref": "container", "y": 0.99, "yanchor": "top"})
    return fig


def _residue_title(run: ModelRun, output: str) -> str:
    result = run.outputs[output].windows
    count = len(view.windows(result))
    return (
        f"{run.name}: {count} of {result.window_count} windows above the "
        f"±{view.tolerance_um(result):.2f} um RMS limit (dashed)"
    )


def top_candidate(run: ModelRun, output: str) -> str | None:
    """The signal the diagnosis of ``run``'s residue ranks first, or None without a ranking."""
    ranked = view.candidates(run.outputs[output].diagnosis)
    return ranked[0].signal if ranked else None


def _overlay_candidate(
    fig: go.Figure, report: ReportData, run: ModelRun, output: str, row: int
) -> None:
    """The top-ranked candidate signal on the panel's second y axis, in its own unit."""
    signal = top_candidate(run, output)
    if signal is None:
        return
    values = report.data.column(signal)
    _, unit = column_unit(signal, declared_units(*(r.evaluation for r in report.runs)))
    fig.add_trace(
        go.Scatter(
            x=time_h(report)[_kept(values)],
            y=drawn(values[_kept(values)]),
            name=f"top candidate: {signal}",
            mode="lines",
            line={"color": CANDIDATE_COLOUR, "width": 0.9},
            opacity=0.6,
            hovertemplate=f"%{{y:.4g}} {unit}",
        ),
        row=row,
        col=1,
        secondary_y=True,
    )
    fig.update_yaxes(
        title_text=f"{signal} ({unit})" if unit else signal,
        title_font={"color": CANDIDATE_COLOUR},
        showgrid=False,
        row=row,
        col=1,
        secondary_y=True,
    )


def contributions(report: ReportData, run: ModelRun, output: str) -> go.Figure:
    """Each sub-model's contribution to ``output`` stacked (um), with their sum and the measurement."""
    x = time_h(report)
    parts = run.contributions(output)
    measured = report.data.column(run.outputs[output].measured_column)
    total = run.evaluation.predicted(output)
    # Stacked areas must share one x: the union of every part's extremes, with
    # fewer buckets per part so the union is half a line's points: a stack of
    # bands reads as shares over time, and it draws two traces per part.
    per_part = max(50, DEFAULT_BUCKETS // (2 * max(1, len(parts))))
    index = minmax_indices(list(parts.values()), per_part)
    fig = go.Figure()
    palette = ("#7fb3d5", "#f1948a", "#82e0aa", "#f8c471", "#bb8fce", "#85c1e9", "#f0b27a")
    # Mixed signs do not stack readably in one pile: positive parts pile up
    # from zero, negative parts pile down from zero, and the black line is
    # their sum (the simulated output).
    for k, (name, y) in enumerate(parts.items()):
        colour = palette[k % len(palette)]
        for group, part in (("above", np.maximum(y, 0.0)), ("below", np.minimum(y, 0.0))):
            if not part.any():
                continue
            fig.add_trace(
                go.Scatter(
                    x=x[index],
                    y=drawn(part[index]),
                    name=name,
                    mode="lines",
                    line={"width": 0.6, "color": colour},
                    fillcolor=colour,
                    stackgroup=group,
                    legendgroup=name,
                    showlegend=not any(t.legendgroup == name for t in fig.data),
                    hovertemplate="%{y:.2f} um",
                )
            )
    fig.add_trace(_line(x, total, _kept(total), "sum (simulated)", "#000000", opacity=0.8))
    fig.add_trace(
        _line(x, measured, _kept(measured), "measured", MEASURED_COLOUR, opacity=0.5).update(
            line={"dash": "dot"}
        )
    )
    fig = _layout(
        fig,
        f"{output}: sub-model contributions of {run.name} (stacked; negative parts below zero)",
        "displacement (um)",
    )
    return legend_under_title(_time_axis(fig, report))


def candidates(run: ModelRun, output: str) -> go.Figure | None:
    """Candidate signals ranked by how much of the residue each explains (%), or None without any."""
    rows = view.candidates(run.outputs[output].diagnosis)
    if not rows:
        return None
    rows = list(reversed(rows))  # plotly draws horizontal bars bottom-up: best on top
    fig = go.Figure(
        go.Bar(
            x=[c.explained_percent for c in rows],
            y=[c.signal for c in rows],
            orientation="h",
            marker={"color": [MODEL_COLOURS[0] if c.significant else "#b8b8b8" for c in rows]},
            text=[f"{c.explained_percent:.1f} %" for c in rows],
            textposition="auto",
            hovertemplate="%{y}: %{x:.1f} % of the residue<extra></extra>",
        )
    )
    fig = _layout(
        fig,
        f"{output}: candidate signals for the residue of {run.name} (grey: not significant)",
        "",
        height=max(220, 60 + 32 * len(rows)),
    )
    # 0..100 % always, so rankings of two models read on one scale; a
    # held-out share can be negative (worse than the residue's mean).
    low = min(0.0, *(c.explained_percent for c in rows))
    fig.update_xaxes(title_text="residue explained (%)", range=[low, 100.0])
    # Signal names are long: leave them room on the left.
    longest = max(len(c.signal) for c in rows)
    fig.update_layout(hovermode="closest", showlegend=False, margin={"l": 20 + 7 * longest})
    return fig


def conditions(report: ReportData) -> go.Figure | None:
    """Operating conditions as small multiples: one panel per unit, sharing the time axis.

    Each panel has its own legend at its top (plotly's multiple legends), so
    a signal's name sits by the panel it is drawn in.
    """
    groups = report.conditions
    if not groups:
        return None
    x = time_h(report)
    data = report.data
    height_px = 70 + 190 * len(groups)
    fig = make_subplots(
        rows=len(groups),
        cols=1,
        shared_xaxes=True,
        vertical_spacing=_panel_gap(len(groups), height_px),
    )
    palette = ("#1f5fa8", "#d1495b", "#2a9d8f", "#e9c46a", "#6a4c93", "#f4a261", "#264653")
    for row, group in enumerate(groups, start=1):
        legend = "legend" if row == 1 else f"legend{row}"
        for i, name in enumerate(group.columns):
            y = data.column(name)
            index = _kept(y)
            fig.add_trace(
                go.Scatter(
                    x=x[index],
                    y=drawn(y[index]),
                    name=name,
                    mode="lines",
                    line={"width": 1.2, "color": palette[i % len(palette)]},
                    legend=legend,
                    hovertemplate=f"%{{y:.3g}} {group.unit}",
                ),
                row=row,
                col=1,
            )
        fig.update_yaxes(title_text=_axis_title(group.label, group.unit), row=row, col=1)
    fig.update_xaxes(title_text="time (h)", row=len(groups), col=1)
    fig.update_layout(
        template="plotly_white",
        height=height_px,
        hovermode="x unified",
        showlegend=True,  # plotly hides a legend of one trace otherwise
    )
    for row in range(1, len(groups) + 1):
        axis = fig.layout["yaxis" if row == 1 else f"yaxis{row}"]
        fig.layout["legend" if row == 1 else f"legend{row}"] = {
            "orientation": "h",
            "x": 0.0,
            "xanchor": "left",
            "y": axis.domain[1],
            "yanchor": "bottom",
            "font": {"size": 11},
        }
    return _time_axis(fig, report)


def _panel_gap(rows: int, height_px: int) -> float:
    """The gap between stacked panels as plotly wants it: a share of the height, < 1 / (rows - 1).

    About 50 px whatever the number of panels: room for the next panel's
    legend, which sits at its top.
    """
    if rows < 2:
        return 0.0
    return min(50.0 / height_px, 0.5 / (rows - 1))


def _axis_title(label: str, unit: str) -> str:
    return f"{label} ({unit})" if unit and unit != label else label
