"""Model files: schema-versioned YAML parsed into frozen model objects.

The schema (``schema: compd.model/1``) is written down in pydantic models with
unknown keys forbidden (:mod:`compd.files.modelschema`). Every problem is reported as
``FILE: line N (outputs.disp_z_um.submodels[2].tf.den): what is wrong. fix``,
and nothing about the coefficients is guessed: each TF states its form
(``continuous`` in s, ``discrete`` in z^-1) and its ``power_order``.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pydantic import ValidationError

from compd.errors import ModelError, ModelFileError
from compd.files.equations import equation_sets
from compd.files.modelschema import (
    SCHEMA,
    ConsistencyDoc,
    GateDoc,
    ModelDoc,
    ResidualDoc,
    TFDoc,
)
from compd.files.yamlplace import BUNDLED, NodeTree, parse_yaml, read_limited, resolve_path, shorten
from compd.files.yamlplace import describe as _describe
from compd.files.yamlplace import where as _where
from compd.model.compiled import CompiledModel, compile_model
from compd.model.consistency import ConsistencyModel
from compd.model.guards import Finding, Severity
from compd.model.guards import check_model as check_plausibility
from compd.model.precompiled import ConversionNeeded, DifferenceEquations, same_period
from compd.model.residual import DoorFeatures, ResidualModel
from compd.model.structure import (
    AmbientZero,
    Gate,
    GateTarget,
    InputSpec,
    Model,
    Output,
    Position,
    SubModel,
)
from compd.model.transfer import ContinuousTF, DiscreteTF


@dataclass(frozen=True)
class ModelFile:
    """A parsed model file: the model, its documentation and where it came from."""

    path: str
    sha256: str
    model: Model
    doc: ModelDoc
    #: Its ``difference_equations``, checked against its TFs (:mod:`compd.files.equations`).
    equations: tuple[DifferenceEquations, ...] = ()

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

    def consistency(self) -> ConsistencyModel | None:
        """How each input follows the others (the daemon's plausibility check); None in older files."""
        doc = self.doc.consistency
        if doc is None:
            return None
        return ConsistencyModel(
            signals=tuple(doc.signals),
            checked=tuple(doc.checked),
            taus_s=tuple(doc.taus_s),
            heated=tuple(doc.heated),
            mean=np.array(doc.mean),
            cov=np.array(doc.covariance),
            low=np.array(doc.low),
            high=np.array(doc.high),
            sigma=tuple(doc.sigma[c] for c in doc.checked),
            max_rate_per_s=tuple(doc.max_rate_per_s[c] for c in doc.checked),
        )

    def output_range(self, output: str) -> tuple[float, float] | None:
        """``(low, high)`` (um) of ``output`` over the calibration; None where the file does not say.

        The measured output's ``[min, max]`` in ``provenance.calibration.ranges``
        (every ``compd fit`` writes the ranges of all its data's columns, the
        output's included; ``compd extend`` widens them), else
        ``±probe_prior.output_peak_um`` (the model's largest ``|output|`` over
        its calibration). A file with neither (written by hand, or before
        either existed) has no calibrated envelope: the daemon then watches the
        clamp only (:mod:`compd.service.loop.envelope`).
        """
        calibration = self.doc.provenance.calibration
        if calibration is not None and output in calibration.ranges:
            low, high = calibration.ranges[output]
            return (min(low, high), max(low, high))
        prior = (self.doc.probe_prior or {}).get(output)
        if prior is not None and prior.output_peak_um > 0:
            return (-prior.output_peak_um, prior.output_peak_um)
        return None

    def compile(self, sample_time_s: float | None = None, *, convert: bool = True) -> CompiledModel:
        """Compile for running; a refusal names this file and the sub-model.

        ``convert=False`` is the daemon's way: only the file's difference
        equations and its discrete TFs at their own rate, with numpy alone; a
        file that would need converting is refused with the command that adds
        the equations.
        """
        try:
            return compile_model(
                self.model, sample_time_s, equations=self.equations, convert=convert
            )
        except ConversionNeeded as exc:
            period_s = self.model.sample_time_s if sample_time_s is None else sample_time_s
            carried = ", ".join(f"{p:g} s" for p in self.runnable_periods_s()) or "none"
            raise ModelFileError(
                self.path,
                f"{exc.message} (it runs as it is at: {carried})",
                where=exc.where,
                fix=f"Add them with 'compd model compile {self.path} --period-s {period_s:g}' "
                "(the modelling toolkit: compd[toolkit]), then start or load the file again",
            ) from exc
        except ModelError as exc:
            raise ModelFileError(self.path, exc.message, where=exc.where) from exc

    def runnable_periods_s(self) -> list[float]:
        """The loop periods (s) ``compd run`` runs this file at without converting, ascending."""
        periods = [e.period_s for e in self.equations]
        own = self.model.sample_time_s
        if not any(same_period(own, p) for p in periods) and not any(
            isinstance(sub.tf, ContinuousTF) for o in self.model.outputs for sub in o.submodels
        ):
            periods.append(own)
        return sorted(periods)


def load_model(path: str | Path) -> ModelFile:
    """Read, validate and build a model file (does not compile; see :meth:`ModelFile.compile`).

    ``bundled:NAME`` names one of the bundled examples (as provenance records them).
    """
    path = model_source(path)
    return parse_model_bytes(read_limited(path, ModelFileError), path)


def model_source(path: str | Path) -> Path:
    """The file a command-line model argument names: a path, or ``bundled:NAME``."""
    return resolve_path(path, Path(".")) if str(path).startswith(BUNDLED) else Path(path)


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
    model = _build(doc, path, root)
    equations = equation_sets(doc.difference_equations, model, path, lambda at: _where(root, at))
    return ModelFile(str(path), sha256, model, doc, equations)


def _build(doc: ModelDoc, path: str | Path, root: NodeTree | None) -> Model:
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
        outputs.append(
            Output(out_name, tuple(subs), _residual(residual, out_name, path), out_doc.bias_um)
        )
    ambient = doc.ambient
    if ambient is not None and declared is not None and ambient.signal not in declared:
        raise ModelFileError(
            path,
            f"ambient signal {ambient.signal!r} is not declared under 'signals'",
            where=_where(root, ("ambient", "signal")),
            fix=f"Declare it with its unit, or use one of {sorted(declared)}",
        )
    zero = (
        None
        if ambient is None
        else AmbientZero(ambient.signal, ambient.reference, tuple(ambient.moves))
    )
    return Model(doc.name, doc.sample_time_s, tuple(outputs), zero)


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
    "too_long": "Give fewer items (see the bounds in docs/commands.md, 'Model files')",
    "less_than_equal": "Give a smaller value (see the bounds in docs/commands.md, 'Model files')",
}


def consistency_doc(model: ConsistencyModel) -> ConsistencyDoc:
    """The model file's ``consistency`` block for ``model``."""
    return ConsistencyDoc(
        signals=list(model.signals),
        checked=list(model.checked),
        taus_s=list(model.taus_s),
        heated=list(model.heated),
        mean=model.mean.tolist(),
        covariance=model.cov.tolist(),
        low=model.low.tolist(),
        high=model.high.tolist(),
        sigma=dict(zip(model.checked, model.sigma, strict=True)),
        max_rate_per_s=dict(zip(model.checked, model.max_rate_per_s, strict=True)),
    )
