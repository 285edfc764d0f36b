"""What a config's sensors can verify of its model: each input's undetectable error, in um per axis.

The numbers are :mod:`compd.model.verifiable`'s; this module takes what they
depend on from the config (the signals read, the plausibility settings, the
axes with their ``tolerance_um``, a gain schedule's rows, redundant partners)
and the model file (its consistency model, its calibration residue).
``compd check-config``, ``compd status`` and ``/metrics`` all read it here.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from compd.model.drift import CusumSettings
from compd.model.verifiable import (
    Unverifiable,
    default_tolerance_um,
    plausibility_detector,
    undetectable_error_um,
)
from compd.service.loop.plausibility import DEFAULT_SETTINGS, PlausibilitySettings
from compd.service.loop.redundancy import ALLOWANCE

if TYPE_CHECKING:
    from compd.files.modelfile import ModelFile
    from compd.model.compiled import CompiledModel
    from compd.service.config.docs import ConfigDoc


def axis_tolerances_um(doc: ConfigDoc, model_file: ModelFile) -> dict[str, float]:
    """Per axis, its ``tolerance_um``, or the default from the model's calibration residue."""
    calibration = model_file.doc.provenance.calibration
    rms = {} if calibration is None else calibration.rms_um
    return {
        axis: o.tolerance_um
        if o.tolerance_um is not None
        else default_tolerance_um(rms.get(o.model_output))
        for axis, o in doc.outputs.items()
    }


def redundant_partners(doc: ConfigDoc) -> dict[str, tuple[str, float]]:
    """Per input with a redundant partner sensor: the partner and the smallest lasting
    disagreement the pair catches (its unit).

    The pair's CUSUM (:mod:`compd.service.loop.redundancy`) sums the excess beyond
    ``ALLOWANCE x tolerance``: a lasting step of twice that is caught within
    ``DECISION_S / ALLOWANCE`` s (400 s), a larger one sooner, a step of the whole
    tolerance at once.
    """
    return {pair.primary: (pair.partner, 2.0 * ALLOWANCE * pair.tolerance) for pair in doc.pairs()}


def config_unverifiable(
    doc: ConfigDoc, model_file: ModelFile, compiled: CompiledModel
) -> list[Unverifiable]:
    """Per input and axis of ``doc``: what a wrong reading can move the axis by unseen (um)."""
    settings = doc.plausibility.settings()
    detect = plausibility_detector(
        model_file.consistency() if settings is not None else None,
        k_sigma=(settings or DEFAULT_SETTINGS).k_sigma,
        min_tolerance=(settings or DEFAULT_SETTINGS).min_tolerance,
        drift=_drift(settings or DEFAULT_SETTINGS),
        available=set(doc.signals),
        partners=redundant_partners(doc),
        without=(
            "the model file has no consistency model"
            if settings is not None
            else "plausibility is off in this config (plausibility.enabled: false)"
        ),
    )
    schedule = doc.gain_schedule
    gain_sets = (
        []
        if schedule is None
        else [row.gains for row in schedule.table]
        + ([schedule.default] if schedule.default else [])
    )
    return undetectable_error_um(
        compiled,
        {axis: o.model_output for axis, o in doc.outputs.items()},
        detect,
        axis_tolerances_um(doc, model_file),
        gain_sets,
    )


def not_verifiable(rows: list[Unverifiable]) -> list[Unverifiable]:
    """The rows beyond their axis's tolerance, the largest first."""
    worst = [r for r in rows if r.exceeds]
    return sorted(worst, key=lambda r: r.undetectable_um, reverse=True)


def model_unverifiable(model_file: ModelFile, compiled: CompiledModel) -> list[Unverifiable]:
    """As :func:`config_unverifiable` without a config: the default plausibility settings, every
    signal the calibration logged read, each model output an axis of the default tolerance."""
    calibration = model_file.doc.provenance.calibration
    rms = {} if calibration is None else calibration.rms_um
    detect = plausibility_detector(
        model_file.consistency(),
        k_sigma=DEFAULT_SETTINGS.k_sigma,
        min_tolerance=DEFAULT_SETTINGS.min_tolerance,
        drift=_drift(DEFAULT_SETTINGS),
    )
    outputs = compiled.output_names
    return undetectable_error_um(
        compiled,
        {name: name for name in outputs},
        detect,
        {name: default_tolerance_um(rms.get(name)) for name in outputs},
    )


class UnverifiableCache:
    """:func:`config_unverifiable` of the running model, computed once per config and model (a few ms)."""

    def __init__(self) -> None:
        self._cached: tuple[ConfigDoc, str, list[Unverifiable]] | None = None

    def rows(
        self, doc: ConfigDoc, model_file: ModelFile, compiled: CompiledModel
    ) -> list[Unverifiable]:
        cached = self._cached
        if cached is None or cached[0] is not doc or cached[1] != model_file.sha256:
            cached = (doc, model_file.sha256, config_unverifiable(doc, model_file, compiled))
            self._cached = cached
        return cached[2]


def _drift(settings: PlausibilitySettings) -> CusumSettings:
    """The drift CUSUM's settings of the daemon's plausibility check."""
    return CusumSettings(settings.drift_k_sigma, settings.drift_h_sigma_h)
