"""The report's HTML tables: metrics, failing windows, candidates (models: :mod:`compd.report.modelcard`).

Metric cells are formatted from the ``compare --json`` summary with the
rounding ``compd compare`` uses on screen (fit % and reductions to 0.1,
micrometres to 0.01), and carry ``data-model``/``data-output``/``data-key``
attributes so a script or a test can read each one back.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from fnmatch import fnmatchcase
from html import escape

from compd.report import analysis_view as view
from compd.report.figures import WINDOW_GRADES, window_grade
from compd.report.gather import ModelRun, ReportData
from compd.toolkit.analysis import CONDITION_PATTERNS
from compd.toolkit.probecompare import ProbeRun
from compd.toolkit.summary import fmt

#: (compare --json key, label, digits): the metrics table's rows, in order.
METRICS: tuple[tuple[str, str, int], ...] = (
    ("fit_percent", "fit (%)", 1),
    ("rms_um", "residue RMS (um)", 2),
    ("peak_to_peak_um", "residue peak-to-peak (um)", 2),
    ("max_abs_um", "max |residue| (um)", 2),
    ("mean_um", "mean residue (um)", 2),
    ("uncompensated_rms_um", "uncompensated RMS (um)", 2),
    ("uncompensated_peak_to_peak_um", "uncompensated peak-to-peak (um)", 2),
    ("rms_reduction_percent", "RMS reduction (%)", 1),
    ("peak_to_peak_reduction_percent", "peak-to-peak reduction (%)", 1),
)
#: Metrics where the second model doing better means a higher / a lower value.
HIGHER_IS_BETTER = ("fit_percent", "rms_reduction_percent", "peak_to_peak_reduction_percent")
LOWER_IS_BETTER = ("rms_um", "peak_to_peak_um", "max_abs_um")


def table(head: Sequence[str], rows: Iterable[Sequence[str]], *, cls: str = "") -> str:
    """An HTML table; cells are already-escaped HTML."""
    attr = f' class="{cls}"' if cls else ""
    header = "".join(f"<th>{h}</th>" for h in head)
    body = "\n".join("<tr>" + "".join(f"<td>{c}</td>" for c in row) + "</tr>" for row in rows)
    return f"<table{attr}><thead><tr>{header}</tr></thead><tbody>\n{body}\n</tbody></table>"


def clock(seconds: float) -> str:
    """Seconds from the record's start as ``H:MM`` (as ``compd compare`` prints window spans)."""
    minutes = round(seconds / 60.0)
    return f"{minutes // 60}:{minutes % 60:02d}"


def metrics_table(report: ReportData, output: str) -> str:
    """fit %, residue and uncompensated figures per model; with two models, the change between them."""
    runs = [(i, r) for i, r in enumerate(report.runs) if output in r.outputs]
    values = [_output_summary(r, output) for _, r in runs]
    head = ["metric", *(f'<span class="swatch m{i}"></span>{escape(r.name)}' for i, r in runs)]
    both = len(runs) == 2
    if both:
        head.append('<span title="second model minus first">change (2nd − 1st)</span>')
    rows = []
    for key, label, digits in METRICS:
        cells = [escape(label)]
        for (i, _), summary in zip(runs, values, strict=True):
            cells.append(
                f'<span data-model="{i}" data-output="{escape(output)}" data-key="{key}">'
                f"{fmt(summary.get(key), digits)}</span>"
            )
        if both:
            cells.append(change_cell(values[0].get(key), values[1].get(key), digits, key))
        rows.append(cells)
    return table(head, rows, cls="metrics")


def per_file_table(report: ReportData, output: str) -> str:
    """Several files: each file's fit % and residue RMS per model, as ``compare`` prints them ("" for one)."""
    runs = [
        (i, r)
        for i, r in enumerate(report.runs)
        if output in r.outputs and r.outputs[output].per_file
    ]
    if not runs:
        return ""
    head = ["file"]
    for i, r in runs:
        swatch = f'<span class="swatch m{i}"></span>{escape(r.name)}'
        head += [f"{swatch}: fit %", f"{swatch}: residue RMS (um)"]
    rows = []
    for k, (name, _) in enumerate(runs[0][1].outputs[output].per_file):
        cells = [f"<code>{escape(name)}</code>"]
        for _, r in runs:
            c = r.outputs[output].per_file[k][1]
            cells += [fmt(c.fit_percent, 1), fmt(c.residue.rms_um, 2)]
        rows.append(cells)
    return "<h3>Each experiment (file or run), the model run from its start</h3>" + table(
        head, rows, cls="per-file"
    )


def _output_summary(run: ModelRun, output: str) -> Mapping[str, float | None]:
    outputs = run.summary["outputs"]
    assert isinstance(outputs, Mapping)
    summary = outputs[output]
    assert isinstance(summary, Mapping)
    return summary


def change_cell(before: float | None, after: float | None, digits: int, key: str) -> str:
    """``after - before`` to ``digits`` decimals, classed better / worse / same for the metric ``key``."""
    if before is None or after is None:
        return "n/a"
    change = after - before
    text = f"{change:+.{digits}f}"
    if abs(change) < 0.5 * 10.0**-digits or key not in (*HIGHER_IS_BETTER, *LOWER_IS_BETTER):
        return f'<span class="same">{text}</span>'
    better = change > 0 if key in HIGHER_IS_BETTER else change < 0
    return f'<span class="{"better" if better else "worse"}">{text}</span>'


_TOLERANCE_SOURCES = {
    "given": "given with --tolerance-um",
    "calibration": "twice the calibration residue RMS",
    "record": "twice this record's residue RMS: the model has no calibration record",
}


def windows_table(run: ModelRun, output: str) -> str:
    """The failing windows of ``run`` on ``output``: span, residue RMS, mean conditions, outside calibration."""
    result = run.outputs[output].windows
    found = view.windows(result)
    source = _TOLERANCE_SOURCES.get(result.tolerance_source, result.tolerance_source)
    caption = (
        f"<p><b>{escape(run.name)}</b>: {len(found)} of {result.window_count} windows of "
        f"{result.window_s / 60:g} min fail: residue RMS above {result.tolerance_um:.2f} um "
        f"({escape(source)}).</p>"
    )
    if not found:
        return caption.replace("</p>", ' <span class="ok">No failing window.</span></p>')
    rows = []
    for k, w in enumerate(found, start=1):
        # The operating conditions compare's table shows (spindle, feed, door,
        # coolant), plus any signal outside the calibration range.
        shown = [
            n
            for n in w.conditions
            if n in w.outside_calibration
            or any(fnmatchcase(n.lower(), p) for p in CONDITION_PATTERNS)
        ]
        conditions = ", ".join(
            f'<span class="worse">{escape(n)} {w.conditions[n]:.4g}</span>'
            if n in w.outside_calibration
            else f"{escape(n)} {w.conditions[n]:.4g}"
            for n in shown
        )
        outside = ", ".join(escape(s) for s in w.outside_calibration) or "—"
        # the grade's colour, as the window is shaded in the residue plot
        colour = WINDOW_GRADES[window_grade(w.rms_um, result.tolerance_um)][2]
        rows.append(
            [
                str(k),
                f"{clock(w.start_s)} – {clock(w.end_s)}",
                f"{w.rms_um:.2f}",
                f'<span class="swatch" style="background: {colour}"></span>'
                f"{w.rms_um / result.tolerance_um:.1f}×",
                conditions,
                outside,
            ]
        )
    head = [
        "#",
        "span (h:mm)",
        "residue RMS (um)",
        "× limit",
        "mean conditions",
        "outside calibration",
    ]
    return caption + collapsed(table(head, rows, cls="windows"), f"{len(rows)} failing windows")


def collapsed(html: str, label: str, *, limit: int = 10) -> str:
    """``html`` folded into a ``<details>`` element when it has more than ``limit`` body rows."""
    if html.count("<tr>") - 1 <= limit:
        return html
    return f"<details><summary>{escape(label)}</summary>{html}</details>"


def candidates_table(run: ModelRun, output: str) -> str:
    """Candidate signals for what the residue still holds, best first, and the verdict."""
    result = run.outputs[output].diagnosis
    rows = [
        [
            str(k),
            escape(c.signal),
            escape(view.effect(result, c.signal)) or "—",
            f"{c.explained_percent:.1f}",
            f"{c.time_constant_s / 60:.1f}",
            f"{c.lag_s / 60:.1f}",
            "+" if c.sign > 0 else "−",
            f"{c.gain_um_per_unit:.3g}",
            f"{c.xcorr_peak:.2f} / {c.xcorr_bound:.2f}",
            "yes" if c.significant else "no",
        ]
        for k, c in enumerate(view.candidates(result), start=1)
    ]
    white = view.residue_white(result)
    parts = [
        f'<p class="{"verdict ok" if white else "verdict"}">{escape(view.verdict(result))}</p>'
    ]
    if rows:
        head = [
            "#",
            "signal",
            "effect",
            "explained (%)",
            "time constant (min)",
            "lag (min)",
            "sign",
            "gain (um/unit)",
            "xcorr peak / 99 % bound",
            "significant",
        ]
        parts.append(table(head, rows, cls="candidates"))
    parts += [f'<p class="muted">{escape(n)}</p>' for n in view.notes(result)]
    return "\n".join(parts)


def probes_table(run: ProbeRun) -> str:
    """The output open loop and with the probe updates, over the same samples (compare's figures)."""
    counts = (
        f"{run.probe_count} probes: {run.count('accepted')} accepted, {run.count('confirmed')} "
        f"taken once confirmed, {run.count('rejected')} rejected, {run.count('flagged')} flagged "
        f"on arrival; prior: {escape(run.prior.prior.source)}"
    )
    rows = []
    for label, c in (("open loop", run.open_loop), ("with probe updates", run.with_probes)):
        rows.append(
            [
                label,
                fmt(c.fit_percent, 1),
                fmt(c.residue.rms_um, 2),
                fmt(c.residue.peak_to_peak_um, 2),
                fmt(c.residue.max_abs_um, 2),
            ]
        )
    change = [
        "change",
        _signed(run.with_probes.fit_percent - run.open_loop.fit_percent, 1),
        _signed(run.with_probes.residue.rms_um - run.open_loop.residue.rms_um, 2),
        _signed(run.with_probes.residue.peak_to_peak_um - run.open_loop.residue.peak_to_peak_um, 2),
        _signed(run.with_probes.residue.max_abs_um - run.open_loop.residue.max_abs_um, 2),
    ]
    head = ["", "fit (%)", "residue RMS (um)", "peak-to-peak (um)", "max |residue| (um)"]
    return f'<p class="muted">{counts}</p>' + table(head, [*rows, change], cls="probes")


def probe_steps_table(run: ProbeRun) -> str:
    """Every probe as the update took it: when, what it measured, the innovation before and after."""
    rows = [
        [
            clock(s.time_s),
            fmt(s.measured_um, 2),
            _signed(s.innovation_before_um, 2),
            _signed(s.innovation_after_um, 2),
            escape(s.result + (" (bounded)" if s.bounded else "")),
        ]
        for s in run.steps
    ]
    head = ["time", "measured (um)", "innovation before (um)", "after (um)", "result"]
    return table(head, rows, cls="probe-steps")


def _signed(value: float, digits: int) -> str:
    """A change with its sign (``+0.42``, ``-1.3``; no sign on zero)."""
    text = fmt(value, digits)
    return text if text.startswith("-") or text == "n/a" or float(text) == 0.0 else f"+{text}"
