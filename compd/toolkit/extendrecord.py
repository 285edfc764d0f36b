"""What ``compd extend`` records in the model file: an extension entry and the widened calibration.

Each extension appends an :class:`~compd.files.modelschema.ExtensionDoc` to
the parent's provenance (parent hash, data, signal, new sub-models, fit before
and after) and widens the recorded calibration, so ``compd compare`` judges
later data against everything the model has now been fitted on. The
parent's figures are not the new model's: they move to
``provenance.base_model``, and the new model leads with its own
(:mod:`compd.files.modelfigures`).
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass

import numpy as np

from compd import __version__
from compd.files.data import DataSet
from compd.files.equations import kept_periods
from compd.files.modelfigures import derived_provenance, extension_headline
from compd.files.modelfile import ModelFile
from compd.files.modelschema import CalibrationDoc, ExtensionDoc, TriedDoc
from compd.files.modelwriter import model_to_yaml
from compd.model.structure import Model
from compd.toolkit.derived import kept_priors, kept_residuals
from compd.toolkit.extendjudge import HeldOut
from compd.toolkit.fitmodel import column_unit


@dataclass(frozen=True)
class Tried:
    """A signal judged for an extension and its held-out figures."""

    signal: str
    held_out: HeldOut

    def doc(self, kept: bool) -> TriedDoc:
        h = self.held_out
        return TriedDoc(
            signal=self.signal,
            held_out_fit_percent_before=h.before,
            held_out_fit_percent_after=h.after,
            error_removed_percent=h.error_removed_percent,
            folds_improved=h.folds_improved,
            folds=h.n_folds,
            kept=kept,
        )


@dataclass(frozen=True)
class ExtensionRecord:
    """What one extension step did: the signal, the sub-models written, what it refitted and tried."""

    signal: str
    submodels: list[str]
    refitted: tuple[str, ...]
    tried: tuple[Tried, ...]
    held_out: HeldOut

    def tried_docs(self) -> list[TriedDoc]:
        tried = self.tried or (Tried(self.signal, self.held_out),)
        return [t.doc(kept=t.signal == self.signal) for t in tried]


def extension_yaml(
    parent: ModelFile,
    model: Model,
    data: DataSet,
    record: ExtensionRecord,
    fit_before: dict[str, float],
    fit_after: dict[str, float],
    command: str,
    *,
    calibration_rms_um: float | None = None,
    output: str = "",
) -> str:
    """``model`` as YAML, ``parent``'s provenance extended by the step ``record`` describes."""
    doc = parent.doc
    units = parent.signal_units()
    signal = record.signal
    if units is not None and signal not in units:
        units = {**units, signal: column_unit(data, signal)}
    calibration = doc.provenance.calibration
    if calibration is not None and calibration_rms_um is not None:
        calibration = widened_calibration(calibration, data, output, calibration_rms_um)
    extension = ExtensionDoc(
        parent_sha256=parent.sha256,
        data=data.path,
        effect_signal=signal,
        submodels=record.submodels,
        fit_percent_before=fit_before,
        fit_percent_after=fit_after,
        created=dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        refitted=list(record.refitted),
        tried=record.tried_docs(),
    )
    provenance = doc.provenance.model_copy(
        update={
            "extensions": [*doc.provenance.extensions, extension],
            "calibration": calibration,
            "compd_version": __version__,
            "command": command or doc.provenance.command,
        }
    )
    if output and fit_after:
        # The parent's figures are not this model's: they move to base_model, named as its.
        provenance = derived_provenance(
            provenance,
            parent_name=parent.model.name,
            parent_sha256=parent.sha256,
            output=output,
            fit_percent=fit_after,
            fit_data=data.path,
        )
        index = len(provenance.extensions) - 1
        provenance = provenance.model_copy(
            update={"headline": extension_headline(extension, index, model.name)}
        )
    return model_to_yaml(
        model,
        description=extended_description(doc.description, signal, record.submodels),
        signals=units,
        provenance=provenance,
        residuals=kept_residuals(parent),
        consistency=doc.consistency,
        probe_prior=kept_priors(parent, model)[0],
        run_periods_s=kept_periods(doc.difference_equations),
    )


def extended_description(description: str, signal: str, submodels: list[str]) -> str:
    """The parent's description and what this extension added, so it describes this model."""
    added = f"extended by compd extend with {signal} ({', '.join(submodels)})"
    return f"{description}; {added}" if description else added


def widened_calibration(
    calibration: CalibrationDoc, data: DataSet, output: str, rms_um: float
) -> CalibrationDoc:
    """The record the model has now been fitted on includes ``data``: widen the seen ranges.

    The calibration RMS (the failing-window tolerance is twice it) becomes the
    larger of the old one and the extended model's RMS on the extension data,
    so windows are not flagged merely for being as good as the fit itself.
    """
    ranges = dict(calibration.ranges)
    for name, values in data.columns.items():
        low, high = float(np.min(values)), float(np.max(values))
        if name in ranges:
            old_low, old_high = ranges[name]
            low, high = min(low, old_low), max(high, old_high)
        ranges[name] = (low, high)
    rms = dict(calibration.rms_um)
    rms[output] = max(rms.get(output, 0.0), rms_um)
    extended_with = [*calibration.extended_with, data.path]
    return calibration.model_copy(
        update={"ranges": ranges, "rms_um": rms, "extended_with": extended_with}
    )
