"""One model's card in the report: name, file, per-input gains judged on the record, sub-models, provenance.

The per-input errors are measured on the report's record, not taken from
the calibration: a model that lacks an effect present in the record leaves
that effect's drift in the residue, and every error grows with it. The card
says so with the figures (:class:`compd.model.stepresponse.GainCheck`), so the
same gains showing ±1.46 in one model and ±0.023 in another read as what they
are: how well this record pins them in each model.
"""

from __future__ import annotations

from html import escape

import numpy as np

from compd.model.stepresponse import GainCheck
from compd.report.gather import ModelRun
from compd.report.inputs import inputs_and_check
from compd.report.provenance import provenance
from compd.report.tables import table

#: How the static gains' standard errors are obtained, printed under the per-input table.
GAIN_ERROR_NOTE = (
    "± one standard error of the static gain on this record: the measured output regressed on "
    "each input's contribution (dynamics held fixed), the least-squares error widened for the "
    "residue's lag-1 autocorrelation; — where it cannot be estimated (a zero or collinear "
    "contribution). 'record's factor': the scale on the input's contribution this record fits "
    "best (1: the record agrees with the gain)."
)
#: What the "applies" column's values mean.
APPLIES_NOTE = (
    "applies: 'always' means the contribution is added at every tick, with no gate switching it "
    "off and no axis position multiplying it; otherwise the gate (a signal above or below a "
    "threshold) or the position factor (um per mm times the position from its reference)."
)
#: A residue this autocorrelated is a drift, not noise: the errors are about the record, not the gains.
DRIFT_AUTOCORRELATION = 0.95


def model_card(run: ModelRun, index: int) -> str:
    """Name, file, sha256, per-input gains, sub-models and provenance of one model."""
    mf = run.evaluation.model_file
    compiled = run.evaluation.compiled
    doc = mf.doc
    parts = [
        f'<h3><span class="swatch m{index}"></span>{escape(compiled.name)}</h3>',
        f"<p>{escape(doc.description)}</p>" if doc.description else "",
        f'<p><code>{escape(mf.path)}</code> · sha256 <code title="{mf.sha256}">'
        f"{mf.sha256[:12]}</code></p>",
    ]
    subs = [
        [
            escape(f"{out}/{sub.name}"),
            escape(sub.effect),
            escape(sub.input.describe()),
            f"{sub.gain:g}",
            escape(sub.describe_factors()),
        ]
        for out, sub in zip(
            (compiled.output_names[o] for o in compiled.output_matrix.argmax(axis=0)),
            compiled.submodels,
            strict=True,
        )
    ]
    for output in run.outputs:
        parts.append(input_table(run, output))
    full = table(["sub-model", "effect", "input", "gain", "applies"], subs, cls="submodels")
    parts.append(f"<details><summary>all {len(subs)} sub-models</summary>{full}</details>")
    parts.append(provenance(run))
    return '<div class="model">' + "\n".join(p for p in parts if p) + "</div>"


def input_table(run: ModelRun, output: str) -> str:
    """One row per input of ``output``: static gain (um per unit) ± its error on the record, time constants."""
    responses, check = inputs_and_check(run, output)
    rows = []
    for r in responses:
        error = "—" if not np.isfinite(r.standard_error) else f"± {r.standard_error:.3g}"
        factor = "—" if not np.isfinite(r.record_factor) else f"{r.record_factor:.3g}"
        taus = ", ".join(f"{t / 60:.3g}" for t in r.time_constants_s) or "static"
        rows.append(
            [
                escape(r.label),
                f'<span data-output="{escape(output)}" data-input="{escape(r.label)}" '
                f'class="static-gain">{r.static_gain:.4g}</span>',
                error,
                factor,
                taus,
                str(len(r.submodels)),
                escape(r.factors),
            ]
        )
    head = [
        "input",
        "static gain (um per unit)",
        "standard error on this record",
        "record's factor",
        "dominant time constants (min)",
        "sub-models",
        "applies",
    ]
    notes = [GAIN_ERROR_NOTE, APPLIES_NOTE]
    if check is not None:
        notes.insert(0, record_note(check, run.evaluation.data.path))
    return (
        f"<h4>{escape(output)}: per input</h4>"
        + table(head, rows, cls="inputs")
        + "".join(f'<p class="muted">{escape(n)}</p>' for n in notes)
    )


def record_note(check: GainCheck, data: str) -> str:
    """What the record's regression left, and what that means for the errors above."""
    text = (
        f"On {data} the regression leaves {check.residue_rms:.3g} um RMS with lag-1 "
        f"autocorrelation {check.lag1_autocorrelation:.3f}, so the errors are widened "
        f"{check.widening:.3g}x."
    )
    if check.lag1_autocorrelation >= DRIFT_AUTOCORRELATION:
        text += (
            " A residue this slow is a drift the model does not explain (an effect it lacks, "
            "or gains this record disagrees with), not noise: these errors say how little this "
            "record pins the gains, not how well they were identified, and the same gains in a "
            "model that explains the drift show far smaller ones."
        )
    return text
