"""The report's first section: what changed on this record and by how much, before anything else.

A reader opens a report to learn whether the new model is better and by how
much; the model ids, sub-models and provenance come after. Per output: the fit
% and the residue RMS and peak-to-peak of each model on this record (the
numbers of ``compd compare --json``, as the metrics tables show them), the
change between them, and each model's own headline figure, named as it is in
its file (:mod:`compd.files.modelfigures`). A model fitted on this very
record is said to be, as its figures here are then not on new data.
"""

from __future__ import annotations

from collections.abc import Mapping
from html import escape
from pathlib import Path

from compd.files.modelfigures import headline_how, model_figures, percent_text
from compd.files.modelfile import ModelFile
from compd.files.modelschema import ProvenanceDoc
from compd.report.gather import ModelRun, ReportData
from compd.toolkit.summary import fmt


def verdict(report: ReportData) -> str:
    """The lead section's HTML: one line per output, each model's headline, and warnings."""
    parts = []
    for output in report.primary.outputs:
        runs = [r for r in report.runs if output in r.outputs]
        summaries = [_summary(r, output) for r in runs]
        parts.append(f'<p class="lead">{_change(output, runs, summaries)}</p>')
    items = [_headline(i, r) for i, r in enumerate(report.runs)]
    items += [
        f"<li>{escape(r.name)} was fitted on <code>{escape(report.data.path)}</code>: its figures "
        "here are on data it was fitted on, not on new data</li>"
        for r in report.runs
        if fitted_on(r.evaluation.model_file, report.data.path)
    ]
    parts.append(f'<ul class="headlines">{"".join(items)}</ul>')
    return "\n".join(parts)


def _change(output: str, runs: list[ModelRun], summaries: list[Mapping[str, object]]) -> str:
    """``fit A -> B (+x points)``, RMS and peak-to-peak the same way; one model: its figures."""
    fit, rms, p2p = ("fit_percent", "rms_um", "peak_to_peak_um")
    if len(runs) == 2:
        before, after = summaries
        lead = (
            f"<b>{escape(output)}: fit {_f(before, fit, 1)} % → {_f(after, fit, 1)} % "
            f"({_diff(before, after, fit, 1)} points)</b>"
        )
        return (
            f"{lead}, residue RMS {_f(before, rms, 2)} → {_f(after, rms, 2)} um "
            f"({_ratio(before, after, rms)}), peak-to-peak {_f(before, p2p, 2)} → "
            f"{_f(after, p2p, 2)} um ({_ratio(before, after, p2p)}), from "
            f"{escape(runs[0].name)} to {escape(runs[1].name)}"
        )
    (only,) = summaries
    return (
        f"<b>{escape(output)}: fit {_f(only, fit, 1)} %</b>, residue RMS {_f(only, rms, 2)} um "
        f"(uncompensated {_f(only, 'uncompensated_rms_um', 2)} um, reduced by "
        f"{_f(only, 'rms_reduction_percent', 1)} %), peak-to-peak {_f(only, p2p, 2)} um "
        f"(uncompensated {_f(only, 'uncompensated_peak_to_peak_um', 2)} um), with "
        f"{escape(runs[0].name)}"
    )


def _headline(index: int, run: ModelRun) -> str:
    figures = model_figures(run.evaluation.model_file.doc)
    swatch = f'<span class="swatch m{index}"></span>{escape(run.name)}'
    h = figures.headline
    if h is None:
        said = figures.not_judged() or "no headline figure recorded in its file"
        return f"<li>{swatch}: {escape(said)}</li>"
    values = escape(percent_text(h.percent))
    return f"<li>{swatch}: {escape(h.name)} {values} ({escape(headline_how(h))})</li>"


def fitted_on(model_file: ModelFile, data_path: str) -> bool:
    """Whether the model's provenance names ``data_path`` among the records it was fitted on.

    Recorded paths are relative to the model file's folder; ``data_path`` to
    the working directory. Paths that name no file (a description) never match.
    """
    target = _resolved(Path(data_path))
    if target is None:
        return False
    folder = Path(model_file.path).parent
    return any(_resolved(folder / p) == target for p in _fitting_paths(model_file.doc.provenance))


def _fitting_paths(prov: ProvenanceDoc) -> list[str]:
    paths = [prov.data, prov.fit_data, *(e.data for e in prov.extensions)]
    if prov.calibration is not None:
        paths += [prov.calibration.data, *prov.calibration.extended_with]
    if prov.base_model is not None:
        paths.append(prov.base_model.data)
    return [p for p in paths if p]


def _resolved(path: Path) -> Path | None:
    try:
        return path.resolve() if path.exists() else None
    except OSError:
        return None


def _summary(run: ModelRun, output: str) -> Mapping[str, object]:
    outputs = run.summary["outputs"]
    assert isinstance(outputs, Mapping)
    summary = outputs[output]
    assert isinstance(summary, Mapping)
    return summary


def _value(summary: Mapping[str, object], key: str) -> float | None:
    value = summary.get(key)
    return float(value) if isinstance(value, int | float) else None


def _f(summary: Mapping[str, object], key: str, digits: int) -> str:
    return fmt(_value(summary, key), digits)


def _diff(before: Mapping[str, object], after: Mapping[str, object], key: str, digits: int) -> str:
    a, b = _value(before, key), _value(after, key)
    return "n/a" if a is None or b is None else f"{b - a:+.{digits}f}"


def _ratio(before: Mapping[str, object], after: Mapping[str, object], key: str) -> str:
    """The relative change, ``-90 %`` for a tenth of what it was."""
    a, b = _value(before, key), _value(after, key)
    if a is None or b is None or a == 0.0:
        return "n/a"
    return f"{100.0 * (b - a) / a:+.0f} %".replace("-", "−")
