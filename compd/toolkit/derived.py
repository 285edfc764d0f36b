"""What a model file derived from another (``compd update``, ``compd extend``) keeps of its parent.

The daemon relies on more than the sub-models: each output's residual forest,
the inputs' consistency checks, the loop periods, the probe prior. A derived
file keeps each unless the change makes it wrong; what it cannot keep it
says, so a daemon never runs quietly without it.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from compd.files.modelfile import ModelFile
from compd.files.modelschema import ProbePriorDoc, ResidualDoc
from compd.files.probeprior import static_gains
from compd.model.structure import Model


def kept_residuals(parent: ModelFile) -> dict[str, ResidualDoc]:
    """The parent's residual-forest blocks, per output (the forests stay: the new file names their sidecars)."""
    return {n: o.residual for n, o in parent.doc.outputs.items() if o.residual is not None}


def kept_priors(parent: ModelFile, model: Model) -> tuple[dict[str, ProbePriorDoc], list[str]]:
    """The parent's probe priors of the outputs ``model`` did not change, and a note per dropped one.

    A prior is the calibration's posterior in the parent's sub-models and
    coefficients. Where only the sub-models' gains changed (``compd update``)
    it is centred on the new coefficients (:func:`recentred`). An output whose
    sub-models changed otherwise would start its probe update from parameters
    it no longer has, so it gets none (the daemon's conservative default,
    which it logs), and the command says so.
    """
    before = {o.name: o.submodels for o in parent.model.outputs}
    priors = dict(parent.doc.probe_prior or {})
    kept: dict[str, ProbePriorDoc] = {}
    for output in model.outputs:
        prior = priors.get(output.name)
        if prior is None:
            continue
        if before.get(output.name) == output.submodels:
            kept[output.name] = prior
        elif (moved := recentred(prior, parent.model, model, output.name)) is not None:
            kept[output.name] = moved
    notes = [
        f"{name}: its sub-models changed, so the calibration's probe prior no longer "
        "fits them: the new file has none for it, and a daemon with probes starts its probe "
        "update from the conservative default"
        for name in sorted(set(priors) - set(kept))
        if name in {o.name for o in model.outputs}
    ]
    return kept, notes


def recentred(
    prior: ProbePriorDoc, parent: Model, model: Model, output: str
) -> ProbePriorDoc | None:
    """``prior`` (in the coefficients) centred on ``model``'s where only gains changed, else None.

    The calibration's uncertainty about each coefficient is kept as it was
    (wider than what the probes behind the new gains taught: the update
    starts no surer than the calibration left it); the gains' posterior,
    relative to each coefficient, is scaled with it.
    """
    if prior.coefficients is None:
        return None
    old = {o.name: o.submodels for o in parent.outputs}.get(output, ())
    new = next((o.submodels for o in model.outputs if o.name == output), ())
    if len(old) != len(new) or any(
        replace(a, gain=b.gain) != b for a, b in zip(old, new, strict=True)
    ):
        return None
    before, after = static_gains(parent, output), static_gains(model, output)
    if before is None or after is None or list(after) != prior.parameters[:-1]:
        return None
    scale = np.array([after[n] / before[n] if before[n] else 1.0 for n in after] + [1.0])
    gains = prior.gains_covariance
    return prior.model_copy(
        update={
            "coefficients": [after[n] for n in after],
            "gains_covariance": None
            if gains is None
            else (np.asarray(gains) * np.outer(scale, scale)).tolist(),
        }
    )


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
