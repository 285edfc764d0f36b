"""The identification checks MATLAB's System Identification Toolbox users look for, as plotly figures.

* :func:`step_responses`: each input's step response (``step``), um per unit
  of the input over time, one small panel per input, its static gain dashed.
* :func:`correlations`: the residue test (``resid``): the residue's
  autocorrelation and its cross-correlation with each model input and the
  diagnosis's leading candidates, each inside its 99 % Bartlett band
  (:mod:`compd.model.correlation`, the bounds ``compd diagnose`` uses).

Panels carry their names in subplot titles and the figures have no legend,
so nothing overlaps a title.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import plotly.graph_objects as go
from plotly.subplots import make_subplots

from compd.model.correlation import correlate
from compd.model.diagnose import MAX_LAG_S
from compd.report import analysis_view as view
from compd.report.decimate import minmax_indices
from compd.report.figures import MODEL_COLOURS, drawn
from compd.report.gather import ModelRun, column_unit, declared_units
from compd.report.inputs import input_responses

#: Panels per row of the small multiples.
COLUMNS = 3
#: The diagnosis's leading candidates shown beside the model inputs in the residue test.
CANDIDATE_PANELS = 3
BAND_COLOUR = "rgba(31, 95, 168, 0.15)"
_PANEL_PX = 210
_DRAWN_POINTS = 240
#: Points of a bound band's edge (the bounds change slowly with the lag).
_BAND_POINTS = 40


def _grid(titles: list[str], title: str) -> go.Figure:
    rows = -(-len(titles) // COLUMNS)
    height = 90 + _PANEL_PX * rows
    fig = make_subplots(
        rows=rows,
        cols=COLUMNS,
        subplot_titles=titles,
        vertical_spacing=min(70.0 / height, 0.5 / max(rows - 1, 1)),
        horizontal_spacing=0.08,
    )
    fig.update_layout(
        title={"text": title, "x": 0.0, "xanchor": "left", "font": {"size": 15}},
        template="plotly_white",
        height=height,
        margin={"l": 70, "r": 20, "t": 80, "b": 50},
        showlegend=False,
        hovermode="closest",
    )
    for annotation in fig.layout.annotations:
        annotation.update(font={"size": 12})
    return fig


def _bottom_titles(fig: go.Figure, count: int, text: str) -> None:
    """The x axis title on the lowest panel of each column only: none runs into a panel title below."""
    for k in range(max(0, count - COLUMNS), count):
        fig.update_xaxes(title_text=text, **_cell(k))


def _cell(k: int) -> dict[str, int]:
    return {"row": k // COLUMNS + 1, "col": k % COLUMNS + 1}


def step_responses(run: ModelRun, output: str) -> go.Figure | None:
    """One panel per input of ``output``: the output's response (um) to a unit step of it."""
    found = input_responses(run, output)
    if not found:
        return None
    units = declared_units(run.evaluation)
    titles = []
    for r in found:
        unit = column_unit(r.label.split(" - ")[0], units)[1] or "unit"
        error = "" if not np.isfinite(r.standard_error) else f" ± {r.standard_error:.2g}"
        per = f"um/mm per {unit}" if "mm)" in r.factors else f"um per {unit}"
        titles.append(f"{r.label}: {r.static_gain:.3g}{error} {per}")
    fig = _grid(
        titles,
        f"{output}: step response of {run.name} to each input (unit step at 0; ± one standard "
        "error on this record, see the model's card)",
    )
    for k, r in enumerate(found):
        keep = np.unique(np.linspace(0, len(r.time_s) - 1, _DRAWN_POINTS).astype(int))
        fig.add_trace(
            go.Scatter(
                x=drawn(r.time_s[keep] / 3600.0),
                y=drawn(r.step_um[keep]),
                name=r.label,
                mode="lines",
                line={"color": MODEL_COLOURS[0], "width": 1.6},
                hovertemplate="%{x:.2f} h: %{y:.3g} um<extra></extra>",
            ),
            **_cell(k),
        )
        fig.add_hline(
            y=r.static_gain, line={"color": "#888888", "dash": "dash", "width": 1}, **_cell(k)
        )
    _bottom_titles(fig, len(found), "hours after the step")
    fig.update_yaxes(title_text="um per unit", col=1)
    return fig


@dataclass(frozen=True, eq=False)
class CorrelationPanel:
    """One correlation over lags (s) and its 99 % bound per lag."""

    title: str
    lags_s: np.ndarray
    values: np.ndarray
    bound: np.ndarray


def correlation_panels(run: ModelRun, output: str) -> tuple[CorrelationPanel, ...]:
    """The residue's autocorrelation, then its cross-correlation with each model input and top candidate."""
    evaluation = run.evaluation
    data = evaluation.data
    residue = data.column(run.outputs[output].measured_column) - evaluation.predicted(output)
    compiled = evaluation.compiled
    row = compiled.output_matrix[compiled.output_names.index(output)]
    names = list(
        dict.fromkeys(compiled.submodels[int(i)].input.signal for i in np.flatnonzero(row))
    )
    names += [c.signal for c in view.candidates(run.outputs[output].diagnosis)[:CANDIDATE_PANELS]]
    names = [n for n in dict.fromkeys(names) if data.has(n) and np.ptp(data.column(n)) > 0.0]
    finite = np.isfinite(residue)
    max_lag = int(min(MAX_LAG_S / data.sample_time_s, finite.sum() // 4))
    if max_lag < 1 or not names:
        return ()
    inputs = np.array([data.column(n)[finite] for n in names])
    corr = correlate(residue[finite], inputs, max_lag)
    lags_s = np.arange(max_lag + 1) * data.sample_time_s
    auto_bound = corr.autocorrelation_bound.copy()
    auto_bound[0] = auto_bound[1] if len(auto_bound) > 1 else np.nan
    panels = [CorrelationPanel("residue autocorrelation", lags_s, corr.autocorrelation, auto_bound)]
    panels += [
        CorrelationPanel(
            f"residue × {name} (input leads)",
            lags_s,
            corr.cross[i],
            np.full(len(lags_s), corr.cross_bound[i]),
        )
        for i, name in enumerate(names)
    ]
    return tuple(panels)


def correlations(run: ModelRun, output: str) -> go.Figure | None:
    """The residue test as small multiples: each correlation in its ±99 % bound band (shaded)."""
    panels = correlation_panels(run, output)
    if not panels:
        return None
    fig = _grid(
        [p.title for p in panels],
        f"{output}: residue test of {run.name}: correlations and their 99 % bounds (shaded)",
    )
    for k, p in enumerate(panels):
        keep = minmax_indices([p.values], _DRAWN_POINTS // 2)
        x = drawn(p.lags_s[keep] / 60.0)
        edge = np.unique(np.linspace(0, len(p.lags_s) - 1, _BAND_POINTS).astype(int))
        band = drawn(p.bound[edge])
        band_x = drawn(p.lags_s[edge] / 60.0)
        fig.add_trace(
            go.Scatter(
                x=np.concatenate([band_x, band_x[::-1]]),
                y=np.concatenate([band, -band[::-1]]),
                name="99 % bound",
                fill="toself",
                fillcolor=BAND_COLOUR,
                line={"width": 0},
                hoverinfo="skip",
            ),
            **_cell(k),
        )
        fig.add_trace(
            go.Scatter(
                x=x,
                y=drawn(p.values[keep]),
                name=p.title,
                mode="lines",
                line={"color": MODEL_COLOURS[0], "width": 1.3},
                hovertemplate="lag %{x:.1f} min: %{y:.2f}<extra></extra>",
            ),
            **_cell(k),
        )
    _bottom_titles(fig, len(panels), "lag (min)")
    fig.update_yaxes(range=[-1.05, 1.05])
    fig.update_yaxes(title_text="correlation", col=1)
    return fig
