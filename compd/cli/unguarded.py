"""What a model file leaves a daemon without, said by ``compd model check``, ``check-config`` and ``model load``.

A model file written by hand, by an older compd, or derived by a command that
could not keep everything (``compd extend`` changes the coefficients its probe
prior describes) still runs: these lines say what runs without, rather than
an unqualified "ok". The daemon logs the same at its start.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from compd.files.modelfile import ModelFile
    from compd.model.compiled import CompiledModel
    from compd.service.config.loading import Config


def prior_note(model_file: ModelFile, compiled: CompiledModel, output: str) -> str | None:
    """Why ``output``'s probe update would start from the conservative default; None: the calibration's."""
    from compd.files.probeprior import output_prior
    from compd.model.proberegressors import output_columns

    _, names = output_columns(compiled, output)
    return output_prior(model_file, output, names).note


def no_envelope_note(model_file: ModelFile, output: str, clamp: str) -> str | None:
    """What judges ``output``'s offset when the file records no calibrated range of it; None: it does."""
    if model_file.output_range(output) is not None:
        return None
    return (
        f"{output}: the model file records no calibrated range of it (no provenance.calibration "
        f"range, no probe prior): {clamp} alone judges its offset, an offset extrapolated beyond "
        "anything calibrated is written as long as it is inside the clamp; refit with compd fit "
        "to record one"
    )


def envelope_line(
    model_file: ModelFile, output: str, margin: float | None, after_s: float, clamp_um: float
) -> str:
    """How the daemon judges the offset of the axis that writes ``output`` (:mod:`compd.service.loop.envelope`)."""
    clamp = f"the clamp (|offset| <= {clamp_um:g} um)"
    if margin is None:
        return f"note: envelope_margin: null: {clamp} alone judges its offset"
    note = no_envelope_note(model_file, output, clamp)
    if note is not None:
        return f"note: {note}"
    low, high = model_file.output_range(output) or (0.0, 0.0)
    return (
        f"envelope: {output} {low:.4g}..{high:.4g} um over the calibration, widened by "
        f"{margin:.0%} of its span; outside it or at the clamp for {after_s:g} s the axis is faulted"
    )


def load_notes(config: Config, model_file: ModelFile, compiled: CompiledModel) -> list[str]:
    """What the daemon runs ``model_file`` without, under ``config`` (``compd model load`` says it)."""
    doc = config.doc
    notes = []
    if doc.plausibility.enabled and model_file.consistency() is None:
        notes.append(
            f"{model_file.path} has no consistency model: the daemon checks its inputs one by "
            "one, a wrong reading within its limits is not caught and no input has a stand-in; "
            "refit with compd fit to add one"
        )
    for o in doc.outputs.values():
        clamp = f"the clamp (|offset| <= {o.max_offset_um:g} um)"
        if doc.safety.envelope_margin is not None:
            notes.append(no_envelope_note(model_file, o.model_output, clamp) or "")
    probes = doc.probes
    if probes is not None and probes.enabled:
        for axis in probes.axes:
            notes.append(prior_note(model_file, compiled, doc.outputs[axis].model_output) or "")
    return [note for note in notes if note]


def unchecked_note(model_file: ModelFile, compiled: CompiledModel) -> str | None:
    """The model inputs its consistency model does not predict (e.g. added by ``compd extend``); None: none."""
    doc = model_file.doc.consistency
    if doc is None:
        return None  # said on its own: no consistency model at all
    inputs = dict.fromkeys(sub.input.signal for sub in compiled.submodels)
    unchecked = [name for name in inputs if name not in doc.checked]
    if not unchecked:
        return None
    return (
        f"not checked against the other signals: {', '.join(unchecked)} (model inputs its "
        "consistency model does not predict, e.g. added by compd extend after the fit): each "
        "is checked on its own, a wrong reading within its limits is not caught and it has no "
        "stand-in; refit with compd fit with them among --inputs to check them"
    )


def unranged_note(config: Config, model_file: ModelFile, compiled: CompiledModel) -> str | None:
    """The model inputs the config reads without a range check (``checks.min``/``max``); None: none."""
    signals = config.doc.signals
    bare = [
        name
        for name in compiled.signals
        if name in signals
        and (signals[name].checks.min is None or signals[name].checks.max is None)
    ]
    if not bare:
        return None
    cross = config.doc.plausibility.enabled and model_file.consistency() is not None
    caught = (
        "only the check against the other signals catches"
        if cross
        else "nothing catches (no check against the other signals either)"
    )
    return (
        f"no range check on model input(s) {', '.join(bare)} (checks min and max): a reading no "
        f"machine gives (an open Pt100 reads ~850 degC) {caught} before the model uses it; set "
        "checks: {min: ..., max: ...} to what the machine can read"
    )
