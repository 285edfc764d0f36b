"""The model-file schema ``compd.model/1``, written down in pydantic models.

Every key a model file may hold, with its type and bounds. An unknown key in
what the model does is refused; in its provenance (what the toolkit recorded
about it) it is kept, so that a file fitted by a newer compd still loads.
:mod:`compd.files.modelfile` validates a file's YAML against
:class:`ModelDoc` and builds the model from it; the provenance documents
(calibration, extensions, updates, denoising, cross-validation) are written by
the toolkit and kept with the model.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from compd.files.equations import MAX_PERIODS, DifferenceEquationsDoc
from compd.model.limits import MAX_DELAY_SAMPLES, MAX_ORDER, MAX_SAMPLE_TIME_S, MAX_SUBMODELS
from compd.schemas import MODEL_SCHEMA

SCHEMA = MODEL_SCHEMA

FiniteFloat = Annotated[float, Field(allow_inf_nan=False)]
#: The largest count a file may record (samples, folds, trees): 2^53, the largest integer a
#: float holds exactly. Beyond it a count is corrupt, and arithmetic with floats overflows.
MAX_COUNT = 2**53
#: A random seed: numpy's generators take up to 128 bits.
MAX_SEED = 2**128 - 1


class _Strict(BaseModel):
    """What the model does: an unknown key here could change the offsets, so it is refused."""

    # Patterns matched by Python's re (written with \Z, which ends a value as Rust's $ does):
    # each Rust regex pydantic compiles costs the daemon 0.1-0.3 MB. Schemas built when first
    # used: a section's own validator only where it is validated alone.
    model_config = ConfigDict(
        extra="forbid", frozen=True, strict=False, regex_engine="python-re", defer_build=True
    )


class _Record(BaseModel):
    """What the toolkit recorded about a model: unknown keys are kept, not refused.

    A model file fitted by a newer compd records more (issue 20 added
    ``cross_validation.fold_median_percent``); the model itself is the same, so a
    daemon or toolkit of this version loads it, and rewrites it with those keys
    (``extend``, ``update``). ``compd model check`` lists them
    (:func:`unread_provenance_keys`).
    """

    model_config = ConfigDict(
        extra="allow", frozen=True, strict=False, regex_engine="python-re", defer_build=True
    )


class SignalDoc(_Strict):
    unit: str
    description: str = ""


class InputDoc(_Strict):
    signal: str = Field(min_length=1)
    minus: str | None = None
    reference: Literal["start"] | FiniteFloat = "start"


class AmbientDoc(_Strict):
    """The thermal zero follows the shop air: fixed references of ``moves`` shift by ``signal - reference``."""

    signal: str = Field(min_length=1)
    reference: FiniteFloat
    #: The input signals whose fixed references move with it (temperatures).
    moves: tuple[str, ...] = ()


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
    """Pahk 2002's slope term: the sub-model's contribution times ``(signal - reference_mm)``."""

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
    gain_name: str | None = Field(
        default=None, min_length=1, pattern=r"^[A-Za-z_][A-Za-z0-9_.-]*\Z"
    )
    gate: GateDoc | None = None
    position: PositionDoc | None = None


class ResidualFiguresDoc(_Strict):
    peak_to_peak_um: FiniteFloat
    rms_um: FiniteFloat


class ResidualDoc(_Strict):
    """Swiss-lathe paper's stacked term: a random forest on smoothed door features, arrays in a sidecar."""

    kind: Literal["random_forest"] = "random_forest"
    signal: str = Field(min_length=1)
    threshold: FiniteFloat = 0.5
    time_constants_s: list[Annotated[float, Field(gt=0, allow_inf_nan=False)]] = Field(min_length=1)
    #: A file name beside the model file, no folder: a model file (one a client sends the daemon
    #: too) names nothing elsewhere, and an installed model's forest is beside it.
    file: str = Field(min_length=1, max_length=255)
    sha256: str = Field(pattern=r"^[0-9a-f]{64}\Z")
    trees: int | None = Field(default=None, ge=1, le=MAX_COUNT)
    max_depth: int | None = Field(default=None, ge=1, le=MAX_COUNT)
    seed: int | None = Field(default=None, ge=0, le=MAX_SEED)
    calibration_tf_alone: ResidualFiguresDoc | None = None
    calibration_stacked: ResidualFiguresDoc | None = None

    @field_validator("file")
    @classmethod
    def _beside(cls, file: str) -> str:
        if file in (".", "..") or any(c in file for c in "/\\\x00"):
            raise ValueError(
                "must be a file name beside the model file, with no folder (compd fit and "
                "compd residual write MODEL.residual.npz)"
            )
        return file


class OutputDoc(_Strict):
    """One output: the sum of its sub-models, a residual model's term, and ``bias_um``.

    ``bias_um``: a constant added to the output (um); ``compd model export
    --updated`` writes the bias the probes taught (issue 35). A daemon older
    than the field refuses such a file rather than drop the bias.
    """

    unit: Literal["um"] = "um"
    description: str = ""
    bias_um: FiniteFloat = 0.0
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


class CalibrationDoc(_Record):
    """What the model was fitted on: `compare` judges new data against it.

    ``rms_um`` is the free-run residue RMS per output on the calibration data
    (the default failing-window tolerance is twice it); ``ranges`` is
    ``[min, max]`` of every signal column of that data, so operating
    conditions outside what the model has seen can be named. ``fit_percent``:
    the model's fit on ``data``. An extended model has also been fitted on
    ``extended_with`` (``compd extend``'s records): the ranges cover them, its
    ``rms_um`` is the larger of the calibration's and its own on them, and the
    fit of the output it extended is left out (the model before the extension
    was fitted on ``data``; its figure is in ``provenance.base_model``).
    """

    data: str
    samples: int = Field(ge=1, le=MAX_COUNT)
    sample_time_s: FiniteFloat = Field(gt=0)
    fit_percent: dict[str, FiniteFloat] = Field(default_factory=dict)
    rms_um: dict[str, FiniteFloat] = Field(default_factory=dict)
    ranges: dict[str, tuple[FiniteFloat, FiniteFloat]] = Field(default_factory=dict)
    extended_with: list[str] = Field(default_factory=list)


class TriedDoc(_Record):
    """One signal ``compd extend`` judged: the model's held-out fit without and with it, and the rule's figures."""

    signal: str
    held_out_fit_percent_before: FiniteFloat
    held_out_fit_percent_after: FiniteFloat
    error_removed_percent: FiniteFloat
    folds_improved: int = Field(ge=0, le=MAX_COUNT)
    folds: int = Field(ge=0, le=MAX_COUNT)
    kept: bool = False


class ExtensionDoc(_Record):
    """One ``compd extend`` step: a sub-model added by superposition (Horejs 2015, sect. 4.3)."""

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
    #: Signals of earlier extensions on the same record, re-identified together with this one.
    refitted: list[str] = Field(default_factory=list)
    #: The signals compared (``--effect A,B`` or ``auto``), the kept one included.
    tried: list[TriedDoc] = Field(default_factory=list)


class CharacteristicDoc(_Record):
    """Post-process 2024, eq. 7: gain bounds from per-segment optima on a continuously measured run."""

    data: str
    segment_signal: str
    segments: int = Field(ge=0, le=MAX_COUNT)
    bounds: dict[str, tuple[FiniteFloat, FiniteFloat]] = Field(default_factory=dict)
    fit_percent_before: FiniteFloat | None = None
    fit_percent_after: FiniteFloat | None = None


class UpdateDoc(_Record):
    """One ``compd update`` step: named gains re-optimised on sparse probe measurements (Post-process 2024, eq. 8).

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
    seed: int | None = Field(default=None, ge=0, le=MAX_SEED)
    created: str | None = None


class ProbeUsedDoc(_Record):
    """One probe behind a ``compd model export --updated``: when it touched (unix s), what it gave (um)."""

    touched_s: FiniteFloat
    output: str
    source: str
    result: str
    measured_um: FiniteFloat | None = None
    innovation_before_um: FiniteFloat | None = None
    innovation_after_um: FiniteFloat | None = None


class ProbeUpdateDoc(_Record):
    """One ``compd model export --updated``: the parent's parameters as the daemon's probes updated them.

    ``parameters``: per output, each sub-model's learned factor on its gain
    and the learned ``bias`` (um); ``probes``: those logged since the last
    reset (issue 35 item 4); ``state``: the learned-state file read.
    """

    parent_sha256: str
    state: str
    probes: list[ProbeUsedDoc] = Field(default_factory=list)
    parameters: dict[str, dict[str, FiniteFloat]] = Field(default_factory=dict)
    created: str | None = None


class DenoisedInputDoc(_Record):
    """One input denoised by ``compd fit --denoise``; RMS values are in the input's ``unit``."""

    input: str
    unit: str = "-"
    #: The first N EMD modes (Swiss-lathe paper: 1).
    imfs_removed: int = Field(default=1, ge=1, le=MAX_COUNT)
    lowpass_tau_s: FiniteFloat = Field(gt=0)
    lowpass_stages: int = Field(ge=1, le=2)
    lowpass_vs_emd_rms: FiniteFloat = Field(ge=0)  # matched causal low-pass minus EMD-denoised
    raw_vs_emd_rms: FiniteFloat = Field(ge=0)  # raw sensor minus EMD-denoised (the noise removed)


class DenoiseDoc(_Record):
    """Swiss-lathe paper denoising: identified on EMD-denoised inputs, run with matched low-passes baked in."""

    method: str
    inputs: list[DenoisedInputDoc] = Field(default_factory=list)
    fit_percent_emd: dict[str, FiniteFloat] = Field(default_factory=dict)
    rms_um_emd: dict[str, FiniteFloat] = Field(default_factory=dict)
    fit_percent_lowpass: dict[str, FiniteFloat] = Field(default_factory=dict)
    rms_um_lowpass: dict[str, FiniteFloat] = Field(default_factory=dict)


class CrossValidationDoc(_Record):
    """How the candidates held on operating cycles they were not fitted on (``compd fit``).

    ``fit_percent``: pooled held-out fit % per candidate method (``mlr`` is
    the static regression on the same inputs), settings chosen by the same
    folds; ``nested_fit_percent``: the same with every setting chosen inside
    each training set only (nested cross-validation), the figure to expect on
    new data of the same kind (absent in files written before compd recorded
    it); ``fold_median_percent``: the median of the held-out folds' nested
    figures, the figure to expect on the next record (:meth:`expected_percent`;
    absent before compd recorded it); ``fold_spread_percent``: their standard
    deviation (files written before the median was recorded expected the
    nested figure less it);
    ``calibration_fit_percent`` the same candidates' fit on all the data they
    were fitted on.
    """

    output: str
    folds: str
    kept: str
    fit_percent: dict[str, FiniteFloat] = Field(default_factory=dict)
    nested_fit_percent: dict[str, FiniteFloat] = Field(default_factory=dict)
    fold_spread_percent: dict[str, FiniteFloat] = Field(default_factory=dict)
    fold_median_percent: dict[str, FiniteFloat] = Field(default_factory=dict)
    calibration_fit_percent: dict[str, FiniteFloat] = Field(default_factory=dict)

    def expected_percent(self, method: str | None = None) -> float | None:
        """The kept (or ``method``'s) figure to expect on new data.

        The median of the held-out folds where the file records it; in older
        files the nested (else cross-validated) figure less the folds' spread.
        """
        name = self.kept if method is None else method
        if name in self.fold_median_percent:
            return self.fold_median_percent[name]
        held_out = self.nested_fit_percent.get(name, self.fit_percent.get(name))
        return None if held_out is None else held_out - self.fold_spread_percent.get(name, 0.0)

    def expected_how(self) -> str:
        """How the kept figure was made, after "nested cross-validation" (empty: nothing more to say)."""
        name = self.kept
        pooled = self.nested_fit_percent.get(name, self.fit_percent.get(name))
        if name in self.fold_median_percent and pooled is not None:
            return median_fold_how(pooled)
        spread = self.fold_spread_percent.get(name)
        return f" less its spread over the folds, {spread:.1f} points" if spread else ""


def median_fold_how(pooled_percent: float, n_folds: int | None = None) -> str:
    """How an expected figure that is the median of the held-out folds was made, after its method."""
    folds = "held-out folds" if n_folds is None else f"{n_folds} held-out folds"
    return f": the median of its {folds}, pooled {pooled_percent:.1f} %"


class HeadlineDoc(_Record):
    """The figure a model leads with, in words a reader recognises, and whose figure it is.

    ``name``: what the figure is ("expected fit on new data", "fit on new
    data"); ``percent``: its value per output (fit %); ``model``: the name of
    the model it was measured for; ``data``: the record it was measured on
    (absent: the calibration's folds); ``description``: how it was measured;
    ``source``: the provenance key it repeats, for scripts
    (``cross_validation.fold_median_percent.lagbank``). Files written before
    compd recorded it have none: :mod:`compd.files.modelfigures` derives it.
    """

    name: str = Field(min_length=1)
    percent: dict[str, FiniteFloat] = Field(default_factory=dict)
    model: str = ""
    data: str | None = None
    description: str = ""
    source: str = ""


class BaseModelDoc(_Record):
    """The model a derived one (``compd extend``) started from, with the figures ``compd fit`` recorded of it.

    These are that model's figures, not the derived model's: its headline,
    its fit on its calibration data (``fit_percent``, on ``data``), how its
    candidates held on held-out folds (``cross_validation``) and what
    ``compd fit`` noted (``notes``).
    """

    name: str = ""
    sha256: str = ""
    data: str | None = None
    fit_percent: dict[str, FiniteFloat] = Field(default_factory=dict)
    headline: HeadlineDoc | None = None
    cross_validation: CrossValidationDoc | None = None
    notes: str = ""


class ProvenanceDoc(_Record):
    """What the toolkit recorded about a model; every figure here is this model's own.

    ``headline``: the figure the model leads with, named in words;
    ``fit_percent``: its fit on the data it was fitted on, ``fit_data``
    (absent: ``data``); ``base_model``: the model an extension started from,
    with that model's figures. Files written before ``base_model`` existed keep
    the fitted model's figures here beside their ``extensions``:
    :mod:`compd.files.modelfigures` says whose each one is.
    """

    headline: HeadlineDoc | None = None
    data: str | None = None
    command: str | None = None
    created: str | None = None
    compd_version: str | None = None
    method: str | None = None
    fit_percent: dict[str, FiniteFloat] = Field(default_factory=dict)
    fit_data: str | None = None
    calibration: CalibrationDoc | None = None
    base_model: BaseModelDoc | None = None
    extensions: list[ExtensionDoc] = Field(default_factory=list)
    updates: list[UpdateDoc] = Field(default_factory=list)
    probe_updates: list[ProbeUpdateDoc] = Field(default_factory=list)
    denoise: DenoiseDoc | None = None
    cross_validation: CrossValidationDoc | None = None
    notes: str = ""


class ConsistencyDoc(_Strict):
    """How each model input follows the other logged signals (:mod:`compd.model.consistency`).

    Written by ``compd fit``; the daemon checks every reading of a ``checked``
    input against its prediction from the others and stands in with the
    prediction while the sensor is wrong (:mod:`compd.service.loop.plausibility`).
    ``mean`` and ``covariance`` are those of the features: per signal its
    value and its low-passes at ``taus_s``, and for a ``heated`` speed also its
    heat feature and that one's low-passes.
    """

    signals: list[str] = Field(min_length=2)
    checked: list[str] = Field(min_length=1)
    taus_s: list[Annotated[float, Field(gt=0, allow_inf_nan=False)]]
    heated: list[str] = Field(default_factory=list)
    mean: list[FiniteFloat]
    covariance: list[list[FiniteFloat]]
    low: list[FiniteFloat]
    high: list[FiniteFloat]
    sigma: dict[str, Annotated[float, Field(ge=0, allow_inf_nan=False)]]
    max_rate_per_s: dict[str, Annotated[float, Field(ge=0, allow_inf_nan=False)]]

    @model_validator(mode="after")
    def _shapes(self) -> ConsistencyDoc:
        unknown = [n for n in [*self.checked, *self.heated] if n not in self.signals]
        if unknown:
            raise ValueError(f"checked and heated must be among its signals; not: {unknown}")
        n = (1 + len(self.taus_s)) * (len(self.signals) + len(self.heated))
        for key in ("mean", "low", "high"):
            if len(getattr(self, key)) != n:
                raise ValueError(
                    f"'{key}' needs {n} values (one per feature), has {len(getattr(self, key))}"
                )
        if len(self.covariance) != n or any(len(row) != n for row in self.covariance):
            raise ValueError(f"'covariance' must be {n} x {n} (one row and column per feature)")
        missing = [c for c in self.checked if c not in self.sigma or c not in self.max_rate_per_s]
        if missing:
            raise ValueError(
                f"'sigma' and 'max_rate_per_s' need every checked signal; missing {missing}"
            )
        return self


class ProbePriorDoc(_Strict):
    """One output's prior for the probe update (:mod:`compd.model.probeupdate`), written by ``compd fit``.

    ``parameters``: the output's sub-models (their gains, 1 in the file) then
    ``bias`` (0); ``covariance``: their prior covariance (gain^2, um^2), the
    calibration's ridge posterior widened by the residue's autocorrelation;
    ``residue_sigma_um``: the calibration residue's standard deviation;
    ``samples`` and ``effective_samples``: the calibration's length and its
    effective sample size; ``output_peak_um``: the largest ``|output|`` of the
    model over its calibration (scales the update's rails). A model file
    without it gets a conservative default.
    """

    parameters: list[str] = Field(min_length=2)
    covariance: list[list[FiniteFloat]]
    residue_sigma_um: FiniteFloat = Field(gt=0)
    samples: int = Field(ge=1, le=MAX_COUNT)
    effective_samples: FiniteFloat = Field(gt=0)
    output_peak_um: FiniteFloat = Field(default=0.0, ge=0)
    #: The parameters are the model's coefficients (issue 42): each sub-model's static gain in
    #: the file (um per input unit), the prior's mean; absent: gains on the sub-models (mean 1).
    coefficients: list[FiniteFloat] | None = None
    #: With ``coefficients``: the calibration's posterior of gains on the sub-models, in the
    #: coefficients' units (um per input unit); the update's ``gains`` member starts from it.
    gains_covariance: list[list[FiniteFloat]] | None = None
    #: Per probe interval (s), the calibration residue's variance that does not persist over it
    #: (um^2): a probe's innovation carries it and the next probe no longer sees it.
    transient_variance_um2: (
        dict[
            Annotated[float, Field(gt=0, allow_inf_nan=False)],
            Annotated[float, Field(ge=0, allow_inf_nan=False)],
        ]
        | None
    ) = None

    @model_validator(mode="after")
    def _shape(self) -> ProbePriorDoc:
        n = len(self.parameters)
        if self.parameters[-1] != "bias":
            raise ValueError("'parameters' end with 'bias'")
        if self.gains_covariance is not None and (
            len(self.gains_covariance) != n or any(len(row) != n for row in self.gains_covariance)
        ):
            raise ValueError(f"'gains_covariance' must be {n} x {n}")
        if self.coefficients is not None and len(self.coefficients) != n - 1:
            raise ValueError(
                f"'coefficients' must have {n - 1} values (one per sub-model, not the bias)"
            )
        if len(self.covariance) != n or any(len(row) != n for row in self.covariance):
            raise ValueError(f"'covariance' must be {n} x {n} (one row and column per parameter)")
        return self


class ModelDoc(_Strict):
    schema_: Literal["compd.model/1"] = Field(alias="schema")
    name: str = Field(min_length=1)
    description: str = ""
    sample_time_s: FiniteFloat = Field(gt=0, le=MAX_SAMPLE_TIME_S)
    signals: dict[str, SignalDoc] | None = None
    ambient: AmbientDoc | None = None
    outputs: dict[str, OutputDoc] = Field(min_length=1)
    #: The TFs as compd run steps them at each loop period, precompiled (compd.files.equations).
    difference_equations: list[DifferenceEquationsDoc] | None = Field(
        default=None, max_length=MAX_PERIODS
    )
    consistency: ConsistencyDoc | None = None
    probe_prior: dict[str, ProbePriorDoc] | None = None
    provenance: ProvenanceDoc = ProvenanceDoc()


def unread_provenance_keys(provenance: ProvenanceDoc) -> list[str]:
    """The provenance's keys this compd does not know (dotted paths), e.g. written by a newer compd."""
    return _unread(provenance, "provenance")


def _unread(record: BaseModel, where: str) -> list[str]:
    found = [f"{where}.{key}" for key in (record.model_extra or {})]
    for name in type(record).model_fields:
        value = getattr(record, name)
        items = value if isinstance(value, list) else [value]
        for index, item in enumerate(items):
            if isinstance(item, _Record):
                place = f"{where}.{name}" + (f"[{index}]" if isinstance(value, list) else "")
                found += _unread(item, place)
    return found
