"""Model files: schema-versioned YAML parsed into frozen model objects.

The schema (``schema: compd.model/1``) is written down in pydantic models with
unknown keys forbidden. Every problem is reported as
``FILE: line N (outputs.disp_z_um.submodels[2].tf.den): what is wrong. fix``,
and nothing about the coefficients is guessed: each TF states its form
(``continuous`` in s, ``discrete`` in z^-1) and its ``power_order``.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from compd.errors import ModelError, ModelFileError
from compd.files.yamlplace import describe as _describe
from compd.files.yamlplace import parse_yaml, read_limited, shorten
from compd.files.yamlplace import where as _where
from compd.model.compiled import CompiledModel, compile_model
from compd.model.guards import Finding, Severity
from compd.model.guards import check_model as check_plausibility
from compd.model.limits import MAX_DELAY_SAMPLES, MAX_ORDER, MAX_SAMPLE_TIME_S, MAX_SUBMODELS
from compd.model.residual import DoorFeatures, ResidualModel
from compd.model.structure import Gate, GateTarget, InputSpec, Model, Output, Position, SubModel
from compd.model.transfer import ContinuousTF, DiscreteTF

SCHEMA = "compd.model/1"

FiniteFloat = Annotated[float, Field(allow_inf_nan=False)]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, strict=False)


class SignalDoc(_Strict):
    unit: str
    description: str = ""


class InputDoc(_Strict):
    signal: str = Field(min_length=1)
    minus: str | None = None
    reference: Literal["start"] | FiniteFloat = "start"


class GateDoc(_Strict):
    signal: str = Field(min_length=1)
    above: FiniteFloat | None = None
    below: FiniteFloat | None = None
    applies_to: Literal["output", "input"] = "output"

    @model_validator(mode="after")
    def _one_threshold(self) -> GateDoc:
        if (self.above is None) == (self.below is None):
            raise ValueError("give exactly one of 'above' or 'below' (the gate's threshold)")
        return self


class PositionDoc(_Strict):
    """Seed 003's slope term: the sub-model's contribution times ``(signal - reference_mm)``."""

    signal: str = Field(min_length=1)
    reference_mm: FiniteFloat = 0.0


class TFDoc(_Strict):
    form: Literal["continuous", "discrete"]
    power_order: Literal["ascending", "descending"]
    num: list[FiniteFloat] = Field(min_length=1, max_length=MAX_ORDER + 1)
    den: list[FiniteFloat] = Field(min_length=1, max_length=MAX_ORDER + 1)
    nk: int = Field(default=0, ge=0, le=MAX_DELAY_SAMPLES)
    delay_s: FiniteFloat = Field(default=0.0, ge=0.0)

    @model_validator(mode="after")
    def _delay_matches_form(self) -> TFDoc:
        if self.form == "continuous" and self.nk:
            raise ValueError(
                "'nk' (delay in samples) is for discrete TFs; use 'delay_s' for a continuous TF"
            )
        if self.form == "discrete" and self.delay_s:
            raise ValueError(
                "'delay_s' is for continuous TFs; use 'nk' (samples) for a discrete TF"
            )
        return self


class SubModelDoc(_Strict):
    name: str = Field(min_length=1)
    effect: str = Field(min_length=1)
    input: InputDoc
    tf: TFDoc
    gain: FiniteFloat = 1.0
    gain_name: str | None = Field(default=None, min_length=1, pattern=r"^[A-Za-z_][A-Za-z0-9_.-]*$")
    gate: GateDoc | None = None
    position: PositionDoc | None = None


class ResidualFiguresDoc(_Strict):
    peak_to_peak_um: FiniteFloat
    rms_um: FiniteFloat


class ResidualDoc(_Strict):
    """Seed 004's stacked term: a random forest on smoothed door features, arrays in a sidecar."""

    kind: Literal["random_forest"] = "random_forest"
    signal: str = Field(min_length=1)
    threshold: FiniteFloat = 0.5
    time_constants_s: list[Annotated[float, Field(gt=0, allow_inf_nan=False)]] = Field(min_length=1)
    file: str = Field(min_length=1)
    sha256: str = Field(pattern=r"^[0-9a-f]{64}$")
    trees: int | None = Field(default=None, ge=1)
    max_depth: int | None = Field(default=None, ge=1)
    seed: int | None = None
    calibration_tf_alone: ResidualFiguresDoc | None = None
    calibration_stacked: ResidualFiguresDoc | None = None


class OutputDoc(_Strict):
    unit: Literal["um"] = "um"
    description: str = ""
    submodels: list[SubModelDoc] = Field(min_length=1, max_length=MAX_SUBMODELS)
    residual: ResidualDoc | None = None

    @field_validator("submodels")
    @classmethod
    def _unique_names(cls, submodels: list[SubModelDoc]) -> list[SubModelDoc]:
        names = [s.name for s in submodels]
        duplicates = sorted({n for n in names if names.count(n) > 1})
        if duplicates:
            raise ValueError(
                f"sub-model names must be unique within an output; repeated: {duplicates}"
            )
        return submodels


class CalibrationDoc(_Strict):
    """What the model was fitted on: `compare` judges new data against it.

    ``rms_um`` is the free-run residue RMS per output on the calibration data
    (the default failing-window tolerance is twice it); ``ranges`` is
    ``[min, max]`` of every signal column of that data, so operating
    conditions outside what the model has seen can be named.
    """

    data: str
    samples: int = Field(ge=1)
    sample_time_s: FiniteFloat = Field(gt=0)
    fit_percent: dict[str, FiniteFloat] = Field(default_factory=dict)
    rms_um: dict[str, FiniteFloat] = Field(default_factory=dict)
    ranges: dict[str, tuple[FiniteFloat, FiniteFloat]] = Field(default_factory=dict)


class ExtensionDoc(_Strict):
    """One ``compd extend`` step: a sub-model added by superposition (seed 001 sect. 4.3)."""

    parent_sha256: str
    data: str
    effect_signal: str
    submodels: list[str] = Field(default_factory=list)
    fit_percent_before: dict[str, FiniteFloat] = Field(default_factory=dict)
    fit_percent_after: dict[str, FiniteFloat] = Field(default_factory=dict)
    verify_data: str | None = None
    verify_fit_percent_before: dict[str, FiniteFloat] = Field(default_factory=dict)
    verify_fit_percent_after: dict[str, FiniteFloat] = Field(default_factory=dict)
    created: str | None = None


class CharacteristicDoc(_Strict):
    """Seed 002 eq. 7: gain bounds from per-segment optima on a continuously measured run."""

    data: str
    segment_signal: str
    segments: int = Field(ge=0)
    bounds: dict[str, tuple[FiniteFloat, FiniteFloat]] = Field(default_factory=dict)
    fit_percent_before: FiniteFloat | None = None
    fit_percent_after: FiniteFloat | None = None


class UpdateDoc(_Strict):
    """One ``compd update`` step: named gains re-optimised on sparse probe measurements (seed 002 eq. 8).

    ``probe_values_um`` holds one list per probed output, aligned with
    ``probe_times_s``; ``null`` where that axis was not probed at that instant.
    """

    parent_sha256: str
    data: str
    probes: str
    probe_times_s: list[FiniteFloat] = Field(default_factory=list)
    probe_values_um: dict[str, list[FiniteFloat | None]] = Field(default_factory=dict)
    bounds: dict[str, tuple[FiniteFloat, FiniteFloat]] = Field(default_factory=dict)
    characteristic: CharacteristicDoc | None = None
    gains_before: dict[str, FiniteFloat] = Field(default_factory=dict)
    gains_after: dict[str, FiniteFloat] = Field(default_factory=dict)
    probe_rms_before_um: FiniteFloat | None = None
    probe_rms_after_um: FiniteFloat | None = None
    fit_percent_before: dict[str, FiniteFloat] = Field(default_factory=dict)
    fit_percent_after: dict[str, FiniteFloat] = Field(default_factory=dict)
    seed: int | None = None
    created: str | None = None


class DenoisedInputDoc(_Strict):
    """One input denoised by ``compd fit --denoise``; RMS values are in the input's ``unit``."""

    input: str
    unit: str = "-"
    imfs_removed: int = Field(default=1, ge=1)  # the first N EMD modes (seed 004: 1)
    lowpass_tau_s: FiniteFloat = Field(gt=0)
    lowpass_stages: int = Field(ge=1, le=2)
    lowpass_vs_emd_rms: FiniteFloat = Field(ge=0)  # matched causal low-pass minus EMD-denoised
    raw_vs_emd_rms: FiniteFloat = Field(ge=0)  # raw sensor minus EMD-denoised (the noise removed)


class DenoiseDoc(_Strict):
    """Seed 004 denoising: identified on EMD-denoised inputs, run with matched low-passes baked in."""

    method: str
    inputs: list[DenoisedInputDoc] = Field(default_factory=list)
    fit_percent_emd: dict[str, FiniteFloat] = Field(default_factory=dict)
    rms_um_emd: dict[str, FiniteFloat] = Field(default_factory=dict)
    fit_percent_lowpass: dict[str, FiniteFloat] = Field(default_factory=dict)
    rms_um_lowpass: dict[str, FiniteFloat] = Field(default_factory=dict)


class CrossValidationDoc(_Strict):
    """How the candidates held on operating cycles they were not fitted on (``compd fit``).

    ``fit_percent``: pooled held-out fit % per candidate method (``mlr`` is
    the static regression on the same inputs); ``calibration_fit_percent``
    the same candidates' fit on all the data they were fitted on.
    """

    output: str
    folds: str
    kept: str
    fit_percent: dict[str, FiniteFloat] = Field(default_factory=dict)
    calibration_fit_percent: dict[str, FiniteFloat] = Field(default_factory=dict)


class ProvenanceDoc(_Strict):
    data: str | None = None
    command: str | None = None
    created: str | None = None
    compd_version: str | None = None
    method: str | None = None
    fit_percent: dict[str, FiniteFloat] = Field(default_factory=dict)
    calibration: CalibrationDoc | None = None
    extensions: list[ExtensionDoc] = Field(default_factory=list)
    updates: list[UpdateDoc] = Field(default_factory=list)
    denoise: DenoiseDoc | None = None
    cross_validation: CrossValidationDoc | None = None
    notes: str = ""


class ModelDoc(_Strict):
    schema_: Literal["compd.model/1"] = Field(alias="schema")
    name: str = Field(min_length=1)
    description: str = ""
    sample_time_s: FiniteFloat = Field(gt=0, le=MAX_SAMPLE_TIME_S)
    signals: dict[str, SignalDoc] | None = None
    outputs: dict[str, OutputDoc] = Field(min_length=1)
    provenance: ProvenanceDoc = ProvenanceDoc()


@dataclass(frozen=True)
class ModelFile:
    """A parsed model file: the model, its documentation and where it came from."""

    path: str
    sha256: str
    model: Model
    doc: ModelDoc

    def signal_units(self) -> dict[str, str] | None:
        """Each declared signal's unit, or None when the file declares no ``signals``."""
        signals = self.doc.signals
        return None if signals is None else {name: s.unit for name, s in signals.items()}

    def findings(self) -> list[Finding]:
        """The guard rails (:mod:`compd.model.guards`) against the calibration this file records.

        Gains are judged against the recorded ranges of the calibration data and
        time constants against its length; a file without a calibration record
        gets only the checks that need no data.
        """
        calibration = self.doc.provenance.calibration
        if calibration is None:
            return check_plausibility(self.model)
        return check_plausibility(
            self.model,
            ranges=calibration.ranges,
            record_s=calibration.samples * calibration.sample_time_s,
        )

    def check_plausible(self) -> list[Finding]:
        """Refuse the file if a guard rail finds an error; return the warnings."""
        findings = self.findings()
        errors = [f for f in findings if f.severity is Severity.ERROR]
        if errors:
            raise ModelFileError(
                self.path,
                "implausible for its own calibration data: "
                + "; ".join(f"{f.output}/{f.submodel}: {f.message}" for f in errors),
                fix=errors[0].fix,
            )
        return findings

    def compile(self, sample_time_s: float | None = None) -> CompiledModel:
        """Compile for running; a refusal names this file and the sub-model."""
        try:
            return compile_model(self.model, sample_time_s)
        except ModelError as exc:
            raise ModelFileError(self.path, exc.message, where=exc.where) from exc


def load_model(path: str | Path) -> ModelFile:
    """Read, validate and build a model file (does not compile; see :meth:`ModelFile.compile`)."""
    path = Path(path)
    return parse_model_bytes(read_limited(path, ModelFileError), path)


def parse_model_bytes(raw: bytes, path: str | Path = "<model>") -> ModelFile:
    """Validate a model file's bytes (as read, or as a client sent them); its sha256 is of these bytes."""
    return parse_model(raw.decode("utf-8", errors="replace"), path, hashlib.sha256(raw).hexdigest())


def parse_model(text: str, path: str | Path = "<model>", sha256: str | None = None) -> ModelFile:
    """Validate model-file text; ``path`` is only used in messages."""
    sha256 = sha256 or hashlib.sha256(text.encode()).hexdigest()
    data, root = parse_yaml(text, path, ModelFileError)
    if not isinstance(data, dict):
        raise ModelFileError(
            path, "expected a mapping with keys schema, name, sample_time_s, outputs"
        )
    if data.get("schema") != SCHEMA:
        raise ModelFileError(
            path,
            f"unsupported or missing schema {shorten(data.get('schema'))}",
            where="schema",
            fix=f"Start the file with 'schema: {SCHEMA}'",
        )
    try:
        doc = ModelDoc.model_validate(data)
    except ValidationError as exc:
        # A misspelt key shows up as "unknown key" plus "missing key"; the
        # unknown one is the more useful to report.
        errors = sorted(exc.errors(), key=lambda e: e["type"] != "extra_forbidden")
        error = errors[0]
        location = tuple(error["loc"])
        raise ModelFileError(
            path,
            _describe(error),
            where=_where(root, location),
            fix=_FIXES.get(error["type"], ""),
        ) from exc
    return ModelFile(str(path), sha256, _build(doc, path, root), doc)


def _build(doc: ModelDoc, path: str | Path, root: yaml.Node | None) -> Model:
    declared = doc.signals
    outputs = []
    for out_name, out_doc in doc.outputs.items():
        subs = []
        for i, sub in enumerate(out_doc.submodels):
            location: tuple[str | int, ...] = ("outputs", out_name, "submodels", i)
            used = [
                sub.input.signal,
                sub.input.minus,
                sub.gate.signal if sub.gate else None,
                sub.position.signal if sub.position else None,
            ]
            undeclared = [s for s in used if s and declared is not None and s not in declared]
            if undeclared:
                raise ModelFileError(
                    path,
                    f"signal(s) {undeclared} are not declared under 'signals'",
                    where=_where(root, location),
                    fix=f"Declare them with their unit, or use one of {sorted(declared or {})}",
                )
            try:
                tf = _tf(sub.tf)
            except ModelError as exc:
                raise ModelFileError(
                    path, exc.message, where=_where(root, (*location, "tf"))
                ) from exc
            subs.append(
                SubModel(
                    name=sub.name,
                    effect=sub.effect,
                    input=InputSpec(
                        sub.input.signal,
                        sub.input.minus,
                        None if sub.input.reference == "start" else float(sub.input.reference),
                    ),
                    tf=tf,
                    gain=sub.gain,
                    gate=_gate(sub.gate),
                    gain_name=sub.gain_name,
                    position=(
                        None
                        if sub.position is None
                        else Position(sub.position.signal, sub.position.reference_mm)
                    ),
                )
            )
        residual = out_doc.residual
        if residual is not None and declared is not None and residual.signal not in declared:
            raise ModelFileError(
                path,
                f"residual signal {residual.signal!r} is not declared under 'signals'",
                where=_where(root, ("outputs", out_name, "residual", "signal")),
                fix=f"Declare it with its unit, or use one of {sorted(declared)}",
            )
        outputs.append(Output(out_name, tuple(subs), _residual(residual, out_name, path)))
    return Model(doc.name, doc.sample_time_s, tuple(outputs))


def _residual(doc: ResidualDoc | None, output: str, path: str | Path) -> ResidualModel | None:
    if doc is None:
        return None
    from compd.files.sidecar import load_sidecar

    forest = load_sidecar(path, doc.file, doc.sha256, output)
    try:
        features = DoorFeatures(doc.signal, tuple(doc.time_constants_s), doc.threshold)
        return ResidualModel(features, forest)
    except ModelError as exc:
        raise ModelFileError(
            path, exc.message, where=f"outputs.{output}.residual", fix="Refit the residual model"
        ) from exc


def _tf(doc: TFDoc) -> DiscreteTF | ContinuousTF:
    num, den = np.asarray(doc.num), np.asarray(doc.den)
    if doc.power_order == "descending":
        num, den = num[::-1], den[::-1]
    if doc.form == "continuous":
        return ContinuousTF.from_coefficients(num, den, doc.delay_s)
    return DiscreteTF.from_coefficients(num, den, doc.nk)


def _gate(doc: GateDoc | None) -> Gate | None:
    if doc is None:
        return None
    above = doc.above is not None
    threshold = doc.above if doc.above is not None else doc.below
    assert threshold is not None  # guaranteed by GateDoc's validator
    return Gate(doc.signal, float(threshold), above, GateTarget(doc.applies_to))


_FIXES = {
    "extra_forbidden": "Remove the key or fix its spelling (see config/README.md for the schema)",
    "missing": "Add the key",
    "literal_error": "Use one of the allowed values",
    "float_parsing": "Give a number",
    "finite_number": "Give a finite number",
    "too_long": "Give fewer items (see the bounds in README.md, 'Model files')",
    "less_than_equal": "Give a smaller value (see the bounds in README.md, 'Model files')",
}
