"""The ``compd compare --json`` object: a contract that scripts, the report and tests read.

Built in one place so that ``compare --json``, the report's embedded summary
and anything else that quotes compare's figures cannot drift apart.
"""

from __future__ import annotations

import math
from typing import Any

# The --json text of every command, here since the toolkit's commands led; the operations
# commands (compd model updates) import it from compd.files, without the toolkit's libraries.
from compd.files.jsontext import json_clean as json_clean
from compd.files.jsontext import json_finite as json_finite
from compd.files.jsontext import json_text as json_text
from compd.model.metrics import Comparison
from compd.toolkit.analysis import DEFAULT_WINDOW_S, WindowsResult
from compd.toolkit.evaluate import Evaluation


def fmt(value: float | None, digits: int = 2) -> str:
    """A figure for a table: ``n/a`` where it is undefined (None or NaN); never ``-0``."""
    if value is None or math.isnan(value):
        return "n/a"
    text = f"{value:.{digits}f}"
    return text[1:] if text.startswith("-") and float(text) == 0.0 else text


def compare_json(evaluation: Evaluation, comparisons: list[Comparison]) -> dict[str, object]:
    """The ``compare --json`` object (key names are a contract, see docs/commands.md)."""
    return {
        "model": evaluation.compiled.name,
        "model_sha256": evaluation.model_file.sha256,
        "data": evaluation.data.path,
        "samples": len(evaluation.data),
        "sample_time_s": evaluation.data.sample_time_s,
        "notes": [*evaluation.data.notes, *evaluation.notes],
        "outputs": {
            c.output: {k: json_clean(v) for k, v in c.as_dict().items() if k != "output"}
            for c in comparisons
        },
    }


def windows_json(results: list[WindowsResult]) -> dict[str, object]:
    """Top-level ``window_s``, ``window_tolerance_sources`` and ``failing_windows`` (a contract)."""
    return {
        "window_s": results[0].window_s if results else DEFAULT_WINDOW_S,
        "window_tolerance_sources": {r.output: r.tolerance_source for r in results},
        "failing_windows": [
            {
                "output": r.output,
                "start_s": w.start_s,
                "end_s": w.end_s,
                # Rounded (to 1 nm and 6 decimals): figures, not bit patterns, across BLAS builds.
                "rms_um": round(w.rms_um, 6),
                "outside_calibration": list(w.outside_calibration),
                "conditions": {k: round(v, 6) for k, v in w.conditions.items()},
            }
            for r in results
            for w in r.windows
        ],
    }


def compare_summary(
    evaluation: Evaluation, comparisons: list[Comparison], windows: list[WindowsResult]
) -> dict[str, Any]:
    """The whole object ``compd compare --json`` prints: metrics, notes and failing windows."""
    summary: dict[str, Any] = compare_json(evaluation, comparisons)
    summary["notes"] = [*summary["notes"], *(n for w in windows for n in w.notes)]
    summary.update(windows_json(windows))
    for w in windows:
        summary["outputs"][w.output]["window_tolerance_um"] = w.tolerance_um
    span = evaluation.span
    summary["from_s"] = None if span is None else span.from_s  # as given; null: from the start
    summary["until_s"] = None if span is None else span.until_s
    return summary
