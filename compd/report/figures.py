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
from compd.report.gather import ModelRun, ReportData

#: One colour per model (primary, compared), the measurement in black.
MODEL_COLOURS = ("#1f5fa8", "#d1495b")
MEASURED_COLOUR = "#222222"
WINDOW_COLOUR = "#f2a541"
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
    measured = report.data.column(runs[0].outputs[output].measured_column)
    simulated = [r.evaluation.predicted(output) for r in runs]
    index = minmax_indices([measured, *simulated], DEFAULT_BUCKETS)
    fig = go.Figure()
    column = runs[0].outputs[output].measured_column
    fig.add_trace(_line(x, measured, index, f"measured ({column})", MEASURED_COLOUR))
    for i, (run, y) in enumerate(zip(runs, simulated, strict=True)):
        fig.add_trace(_line(x, y, index, f"simulated: {run.name}", MODEL_COLOURS[i]))
    return _layout(fig, f"{output}: measured vs simulated (free run)", "displacement (um)")


def residue(report: ReportData, output: str) -> go.Figure:
    """Each model's residue (measured - simulated, um), failing windows shaded, ± tolerance dashed."""
    x = time_h(report)
    runs = [r for r in report.runs if output in r.outputs]
    measured = report.data.column(runs[0].outputs[output].measured_column)
    residues = [measured - r.evaluation.predicted(output) for r in runs]
    index = minmax_indices(residues, DEFAULT_BUCKETS)
    fig = go.Figure()
    for i, (run, y) in enumerate(zip(runs, residues, strict=True)):
        fig.add_trace(_line(x, y, index, f"residue: {run.name}", MODEL_COLOURS[i]))
    primary = runs[0].outputs[output]
    tolerance = view.tolerance_um(primary.windows)
    for sign in (1.0, -1.0):
        fig.add_hline(y=sign * tolerance, line={"color": "#888888", "dash": "dash", "width": 1})
    for window in view.windows(primary.windows):
        fig.add_vrect(
            x0=window.start_s / 3600.0,
            x1=window.end_s / 3600.0,
            fillcolor=WINDOW_COLOUR,
            opacity=0.3,
            line_width=0,
            layer="below",
        )
    failing = (
        f"windows where {runs[0].name} fails shaded"
        if view.windows(primary.windows)
        else f"no window where {runs[0].name} fails"
    )
    title = (
        f"{output}: residue (measured − simulated); {failing}, RMS limit ±{tolerance:.2f} um dashed"
    )
    return _layout(fig, title, "residue (um)")


def contributions(report: ReportData, run: ModelRun, output: str) -> go.Figure:
    """Each sub-model's contribution to ``output`` stacked (um), with their sum and the measurement."""
    x = time_h(report)
    parts = run.contributions(output)
    measured = report.data.column(run.outputs[output].measured_column)
    total = run.evaluation.predicted(output)
    index = minmax_indices([*parts.values(), total, measured], DEFAULT_BUCKETS)
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
    fig.add_trace(_line(x, total, index, "sum (simulated)", "#000000", opacity=0.8))
    fig.add_trace(
        _line(x, measured, index, "measured", MEASURED_COLOUR, opacity=0.5).update(
            line={"dash": "dot"}
        )
    )
    return _layout(
        fig,
        f"{output}: sub-model contributions of {run.name} (stacked; negative parts below zero)",
        "displacement (um)",
    )


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
    """Operating conditions as small multiples, one axis per unit, sharing the time axis."""
    groups = report.conditions
    if not groups:
        return None
    x = time_h(report)
    data = report.data
    fig = make_subplots(
        rows=len(groups),
        cols=1,
        shared_xaxes=True,
        vertical_spacing=0.04,
        subplot_titles=[_axis_title(g.label, g.unit) for g in groups],
    )
    palette = ("#1f5fa8", "#d1495b", "#2a9d8f", "#e9c46a", "#6a4c93", "#f4a261", "#264653")
    for row, group in enumerate(groups, start=1):
        series = [data.column(c) for c in group.columns]
        index = minmax_indices(series, DEFAULT_BUCKETS)
        for i, (name, y) in enumerate(zip(group.columns, series, strict=True)):
            fig.add_trace(
                go.Scatter(
                    x=x[index],
                    y=drawn(y[index]),
                    name=name,
                    mode="lines",
                    line={"width": 1.2, "color": palette[i % len(palette)]},
                    legendgroup=str(row),
                    hovertemplate=f"%{{y:.3g}} {group.unit}",
                ),
                row=row,
                col=1,
            )
        fig.update_yaxes(title_text=group.unit or group.label, row=row, col=1)
    fig.update_xaxes(title_text="time (h)", row=len(groups), col=1)
    fig.update_layout(
        template="plotly_white",
        height=70 + 170 * len(groups),
        margin={"l": 70, "r": 20, "t": 40, "b": 50},
        hovermode="x unified",
        legend={"tracegroupgap": 120},
    )
    return fig


def _axis_title(label: str, unit: str) -> str:
    return f"{label} ({unit})" if unit and unit != label else label
