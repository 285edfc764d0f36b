"""A model file's prior for the probe update: the ``probe_prior`` block, or the documented default.

``compd fit`` stores per output the calibration's posterior in the model's
coefficients (:func:`compd.model.updateprior.coefficient_prior`, issue 42),
with the coefficients it was computed for: a file whose sub-models changed
since (edited, extended) gets the default. Files written before issue 42
hold the posterior of gains on the sub-models
(:func:`compd.model.updateprior.calibration_prior`); a model file without any
(written before, by another tool, or extended since) gets
:func:`compd.model.updateprior.default_prior`: every gain ``1 +- 0.3``, the
bias ``0 +- 2x`` the calibration RMS (the provenance's, else 1 um), and a
note the tools print.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from compd.errors import ModelError
from compd.files.modelfile import ModelFile
from compd.files.modelschema import ProbePriorDoc
from compd.model.structure import Model
from compd.model.updateprior import BIAS, Prior, coefficient_prior, default_prior

#: The calibration RMS a model file that records none is taken to have, um.
UNKNOWN_RMS_UM = 1.0


@dataclass(frozen=True)
class OutputPrior:
    """One output's prior and, when it is the default, why (a note for the user)."""

    prior: Prior
    note: str | None = None


def probe_prior_doc(prior: Prior) -> ProbePriorDoc:
    """The model file's ``probe_prior`` entry for ``prior``."""
    return ProbePriorDoc(
        parameters=list(prior.names),
        covariance=[[float(v) for v in row] for row in prior.covariance],
        residue_sigma_um=prior.residue_sigma_um,
        samples=prior.samples,
        effective_samples=prior.effective_samples,
        output_peak_um=prior.output_peak_um,
        coefficients=None if prior.coefficients is None else prior.coefficients.tolist(),
        gains_covariance=None
        if prior.gains_covariance is None
        else [[float(v) for v in row] for row in prior.gains_covariance],
        transient_variance_um2={i: v for i, v in prior.transient_um2} or None,
    )


def static_gains(model: Model, output: str) -> dict[str, float] | None:
    """Each of ``output``'s sub-models' static gain (um per input unit: gain x TF at steady state).

    None where one has none (an integrator) or it is not finite: the
    coefficients form needs every one.
    """
    gains = {}
    for candidate in model.outputs:
        if candidate.name != output:
            continue
        for sub in candidate.submodels:
            try:
                value = sub.gain * sub.tf.static_gain()
            except ModelError:
                return None
            if not np.isfinite(value):
                return None
            gains[sub.name] = float(value)
    return gains


def output_prior(model_file: ModelFile, output: str, submodels: tuple[str, ...]) -> OutputPrior:
    """``output``'s prior over ``submodels`` (its sub-models' names in the compiled order) and a bias."""
    names = (*submodels, BIAS)
    stored = (model_file.doc.probe_prior or {}).get(output)
    fits = stored is not None and tuple(stored.parameters) == names
    coefficients = None
    if fits and stored is not None and stored.coefficients is not None:
        gains = static_gains(model_file.model, output)
        coefficients = np.array(stored.coefficients, dtype=float)
        now = None if gains is None else np.array([gains[n] for n in submodels])
        fits = now is not None and bool(
            np.allclose(now, coefficients, rtol=1e-6, atol=1e-12 * max(1.0, np.abs(now).max()))
        )
    if fits and stored is not None:
        prior = Prior(
            names,
            np.array(stored.covariance, dtype=float),
            stored.residue_sigma_um,
            stored.samples,
            stored.effective_samples,
            stored.output_peak_um,
            coefficients=coefficients,
            gains_covariance=None
            if coefficients is None or stored.gains_covariance is None
            else np.array(stored.gains_covariance, dtype=float),
            transient_um2=tuple(sorted((stored.transient_variance_um2 or {}).items())),
        )
        return OutputPrior(prior)
    calibration = model_file.doc.provenance.calibration
    rms = None if calibration is None else calibration.rms_um.get(output)
    why = (
        "has no probe_prior for it"
        if stored is None
        else "has a probe_prior for other sub-models or coefficients (changed since the fit)"
    )
    source = (
        f"the calibration RMS {rms:.3g} um" if rms else f"{UNKNOWN_RMS_UM:g} um (no RMS recorded)"
    )
    rms = rms or UNKNOWN_RMS_UM
    note = (
        f"{output}: the model file {why}: the probe update starts from the conservative default "
        f"(every gain 1 +- 0.3, bias 0 +- {2 * rms:.3g} um: twice {source}); refit with "
        "compd fit to store the calibration's own"
    )
    return OutputPrior(default_prior(names, rms), note)


def calibration_probe_priors(
    model: Model,
    outputs: dict[str, dict[str, np.ndarray]],
    measured_um: np.ndarray,
    first: int = 0,
) -> dict[str, ProbePriorDoc]:
    """Each output's ``probe_prior`` entry from its calibration (what ``compd fit`` stores).

    ``outputs``: per output, each sub-model's contribution (um) over the
    calibration in the model's order; ``measured_um``: the measured output
    (one output: what ``compd fit`` identifies); samples before ``first``
    (a ``--from``) are not used. In the model's coefficients
    (:func:`~compd.model.updateprior.coefficient_prior`); an output with a
    sub-model without a static gain gets none (its default applies).
    """
    docs = {}
    for output, terms in outputs.items():
        c = np.column_stack(list(terms.values()))[first:]
        y = np.asarray(measured_um, dtype=float)[first:]
        residue = y - c.sum(axis=1)
        gains = static_gains(model, output)
        if (
            gains is None
            or y.size < 3
            or not np.all(np.isfinite(residue))
            or np.std(residue) <= 0.0
        ):
            continue
        coefficients = np.array([gains[name] for name in terms])
        prior = coefficient_prior(
            (*terms, BIAS), c, residue, coefficients, sample_time_s=model.sample_time_s
        )
        docs[output] = probe_prior_doc(prior)
    return docs
