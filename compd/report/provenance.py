"""The report's provenance of a model: its own figures first, its base model's named as the base's.

Every figure here says whose it is (:mod:`compd.files.modelfigures`): an
extended model leads with its fit on a record it was not fitted on, and the
figures ``compd fit`` recorded of the model it was extended from are listed
as that model's, never as its own.
"""

from __future__ import annotations

from collections.abc import Mapping
from html import escape

from compd.files.modelfigures import figure_lines, model_figures
from compd.files.modelschema import CalibrationDoc, ExtensionDoc
from compd.report.gather import ModelRun
from compd.report.tables import table
from compd.toolkit.summary import fmt


def provenance(run: ModelRun) -> str:
    """Where the model came from: its headline figure, its calibration and its extension history."""
    doc = run.evaluation.model_file.doc
    prov = doc.provenance
    figures = model_figures(doc)
    lines = []
    for lead, rest in figure_lines(figures):
        bold = f"<b>{escape(lead)}</b>" if lead else ""
        lines.append(f'<li class="figure">{bold}{escape(rest)}</li>')
    for label, value in (
        ("data", prov.data),
        ("command", prov.command),
        ("method", prov.method),
        ("created", prov.created),
        ("compd", prov.compd_version),
    ):
        if value:
            lines.append(f"<li>{label}: {escape(str(value))}</li>")
    # An extended file of an older compd keeps its base model's calibration fit and notes here.
    older = prov.base_model is None and bool(prov.extensions)
    if prov.calibration is not None:
        lines += _calibration(prov.calibration, figures.base_label if older else "")
    if prov.notes and not older:
        lines.append(f"<li>notes: {escape(prov.notes)}</li>")
    if figures.base is not None and figures.base.notes:
        lines.append(
            f"<li>notes of {escape(figures.base_label)}: {escape(figures.base.notes)}</li>"
        )
    parts = [f'<ul class="provenance">{"".join(lines)}</ul>'] if lines else []
    if prov.extensions:
        parts.append("<h4>Extensions</h4>" + _extensions(prov.extensions))
    if not parts:
        return '<p class="muted">No provenance recorded in the model file.</p>'
    return "\n".join(parts)


def _calibration(cal: CalibrationDoc, fit_of: str = "") -> list[str]:
    """The calibration record; ``fit_of`` names whose its fit is when it is not this model's."""
    whose = f" of {escape(fit_of)}" if fit_of else ""
    fit = f"fit{whose} {_per_output(cal.fit_percent, '%')}; " if cal.fit_percent else ""
    widened = ""
    if cal.extended_with:
        names = ", ".join(f"<code>{escape(d)}</code>" for d in cal.extended_with)
        widened = (
            f", extended on {names} (the ranges cover them; the residue RMS is the larger of "
            "the calibration's and the extended model's on them)"
        )
    lines = [
        f"<li>calibrated on <code>{escape(cal.data)}</code> ({cal.samples} samples at "
        f"{cal.sample_time_s:g} s){widened}: {fit}residue RMS "
        f"{_per_output(cal.rms_um, 'um', 2)}</li>"
    ]
    ranges = {k: v for k, v in cal.ranges.items() if not k.lower().endswith("_um")}
    if ranges:
        listed = ", ".join(f"{escape(k)} {lo:.4g}…{hi:.4g}" for k, (lo, hi) in ranges.items())
        lines.append(
            f"<li><details><summary>calibration ranges of {len(ranges)} signals</summary>"
            f"{listed}</details></li>"
        )
    return lines


def _extensions(extensions: list[ExtensionDoc]) -> str:
    rows = [
        [
            str(k),
            escape(ext.effect_signal),
            _tried(ext),
            escape(", ".join(ext.submodels)) or "—",
            f"<code>{escape(ext.data)}</code>",
            _before_after(ext.fit_percent_before, ext.fit_percent_after),
            (f"<code>{escape(ext.verify_data)}</code>: " if ext.verify_data else "")
            + _before_after(ext.verify_fit_percent_before, ext.verify_fit_percent_after),
            escape(ext.created or "—"),
        ]
        for k, ext in enumerate(extensions, start=1)
    ]
    head = [
        "#",
        "effect signal",
        "signals tried (held-out fit % with each)",
        "sub-models added",
        "data",
        "fit % before → after",
        "verified on",
        "created",
    ]
    return table(head, rows, cls="extensions")


def _per_output(values: Mapping[str, float], unit: str, digits: int = 1) -> str:
    if not values:
        return "n/a"
    return ", ".join(f"{escape(k)} {v:.{digits}f} {unit}" for k, v in values.items())


def _tried(ext: ExtensionDoc) -> str:
    """The signals ``extend`` compared for this step, the kept one in bold, and what it refitted."""
    cells = [
        (f"<b>{escape(t.signal)}</b>" if t.kept else escape(t.signal))
        + f" {t.held_out_fit_percent_before:.1f} → {t.held_out_fit_percent_after:.1f} "
        f"({t.error_removed_percent:.0f} % of the error, {t.folds_improved}/{t.folds} folds)"
        for t in ext.tried
    ]
    if ext.refitted:
        cells.append("refitted with it: " + escape(", ".join(ext.refitted)))
    return "<br>".join(cells) or "—"


def _before_after(before: Mapping[str, float], after: Mapping[str, float]) -> str:
    keys = list(dict.fromkeys([*before, *after]))
    if not keys:
        return "—"
    return "; ".join(f"{escape(k)} {fmt(before.get(k), 1)} → {fmt(after.get(k), 1)}" for k in keys)
