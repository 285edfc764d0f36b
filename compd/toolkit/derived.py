"""What a model file derived from another (``compd update``, ``compd extend``) keeps of its parent.

The daemon relies on more than the sub-models: each output's residual forest,
the inputs' consistency checks, the loop periods, the probe prior. A derived
file keeps each unless the change makes it wrong; what it cannot keep it
says, so a daemon never runs quietly without it.
"""

from __future__ import annotations

from compd.files.modelfile import ModelFile
from compd.files.modelschema import ProbePriorDoc, ResidualDoc
from compd.model.structure import Model


def kept_residuals(parent: ModelFile) -> dict[str, ResidualDoc]:
    """The parent's residual-forest blocks, per output (the forests stay: the new file names their sidecars)."""
    return {n: o.residual for n, o in parent.doc.outputs.items() if o.residual is not None}


def kept_priors(parent: ModelFile, model: Model) -> tuple[dict[str, ProbePriorDoc], list[str]]:
    """The parent's probe priors of the outputs ``model`` did not change, and a note per dropped one.

    A prior is the calibration's posterior in the parent's sub-models and
    coefficients: an output whose sub-models or gains changed would start its
    probe update from parameters it no longer has, so it gets none (the
    daemon's conservative default, which it logs), and the command says so.
    """
    before = {o.name: o.submodels for o in parent.model.outputs}
    changed = {o.name for o in model.outputs if before.get(o.name) != o.submodels}
    priors = dict(parent.doc.probe_prior or {})
    notes = [
        f"{name}: its sub-models or gains changed, so the calibration's probe prior no longer "
        "fits them: the new file has none for it, and a daemon with probes starts its probe "
        "update from the conservative default"
        for name in sorted(changed & set(priors))
    ]
    return {n: p for n, p in priors.items() if n not in changed}, notes


def consistency_note(parent: ModelFile, signal: str) -> str | None:
    """Why a new input ``signal`` is not checked against the others: the parent's checks predate it."""
    doc = parent.doc.consistency
    if doc is None or signal in doc.checked:
        return None
    return (
        f"{signal}: the consistency checks are the calibration's and do not predict it: the daemon "
        "checks it on its own (no stand-in, a wrong reading within its limits is not caught); "
        "refit with compd fit with it among --inputs to check it against the others"
    )
