"""Writing a model as a ``compd.model/1`` YAML file that :func:`compd.files.modelfile.parse_model` reads back unchanged.

Written by hand rather than with ``yaml.dump`` so the file reads like the
annotated examples in ``config/``: one flow mapping per TF, comments naming
the convention (ascending powers of ``z^-1``, gate semantics), and every
coefficient printed with ``repr`` precision, so a model fitted to 1e-7 um of
static gain is not rounded on its way to the machine. Numbers are always
written in a form YAML 1.1 (PyYAML) reads as floats: ``1.0e-05``, not
``1e-05``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping, Sequence

import yaml

from compd.files.equations import RUN_PERIODS_S, derived_sets
from compd.files.modelschema import (
    SCHEMA,
    ConsistencyDoc,
    ProbePriorDoc,
    ProvenanceDoc,
    ResidualDoc,
)
from compd.model.precompiled import DifferenceEquations
from compd.model.structure import Gate, InputSpec, Model, SubModel
from compd.model.transfer import ContinuousTF, DiscreteTF


def yaml_float(value: float) -> str:
    """``repr`` precision, spelt so PyYAML's float resolver accepts it (a dot, a signed exponent)."""
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"model files hold finite numbers only, got {value}")
    text = repr(value)
    if "e" in text:
        mantissa, exponent = text.split("e")
        if "." not in mantissa:
            mantissa += ".0"
        if exponent[0] not in "+-":
            exponent = "+" + exponent
        text = f"{mantissa}e{exponent}"
    return text


def _string(text: str) -> str:
    """A YAML scalar that reads back as exactly ``text`` (a JSON string is a YAML double-quoted scalar)."""
    return json.dumps(text, ensure_ascii=False)


def _numbers(values: Iterable[float]) -> str:
    return "[" + ", ".join(yaml_float(v) for v in values) + "]"


def _input(spec: InputSpec) -> str:
    parts = [f"signal: {_string(spec.signal)}"]
    if spec.minus is not None:
        parts.append(f"minus: {_string(spec.minus)}")
    reference = "start" if spec.reference is None else yaml_float(spec.reference)
    parts.append(f"reference: {reference}")
    return "{" + ", ".join(parts) + "}"


def _tf(tf: DiscreteTF | ContinuousTF) -> str:
    if isinstance(tf, DiscreteTF):
        return (
            f"{{form: discrete, power_order: ascending, nk: {tf.nk},\n"
            f"             num: {_numbers(tf.num)},\n"
            f"             den: {_numbers(tf.den)}}}"
        )
    return (
        f"{{form: continuous, power_order: ascending, delay_s: {yaml_float(tf.delay_s)},\n"
        f"             num: {_numbers(tf.num)},\n"
        f"             den: {_numbers(tf.den)}}}"
    )


def _gate(gate: Gate) -> str:
    side = "above" if gate.above else "below"
    return (
        f"{{signal: {_string(gate.signal)}, {side}: {yaml_float(gate.threshold)}, "
        f"applies_to: {gate.target.value}}}"
    )


def _submodel(sub: SubModel) -> list[str]:
    lines = [
        f"      - name: {_string(sub.name)}",
        f"        effect: {_string(sub.effect)}",
        f"        input: {_input(sub.input)}",
        f"        tf: {_tf(sub.tf)}",
    ]
    if sub.gain != 1.0:
        lines.append(f"        gain: {yaml_float(sub.gain)}")
    if sub.gain_name is not None:
        lines.append(f"        gain_name: {_string(sub.gain_name)}")
    if sub.gate is not None:
        lines.append(f"        gate: {_gate(sub.gate)}")
    if sub.position is not None:
        lines.append(
            f"        position: {{signal: {_string(sub.position.signal)}, "
            f"reference_mm: {yaml_float(sub.position.reference_mm)}}}"
        )
    return lines


def _residual(doc: ResidualDoc) -> list[str]:
    data = doc.model_dump(mode="json", exclude_none=True)
    text = str(yaml.safe_dump({"residual": data}, sort_keys=False, width=100))
    return [
        "    # Swiss-lathe paper: a random forest on the smoothed door signal, added to the sub-models' "
        "sum; its trees",
        "    # are plain arrays in the .npz named below (checked against sha256 at load)",
        *("    " + line for line in text.rstrip("\n").splitlines()),
    ]


def provenance_lines(provenance: ProvenanceDoc) -> list[str]:
    """The ``provenance:`` block, last in a model file (:mod:`compd.files.provenancepaths` relies on that)."""
    data = provenance.model_dump(mode="json", exclude_defaults=True)
    if not data:
        return []
    text = str(yaml.safe_dump({"provenance": data}, sort_keys=False, allow_unicode=True, width=100))
    return text.rstrip("\n").splitlines()


def model_to_yaml(
    model: Model,
    *,
    description: str = "",
    signals: Mapping[str, str] | None = None,
    provenance: ProvenanceDoc | None = None,
    residuals: Mapping[str, ResidualDoc] | None = None,
    consistency: ConsistencyDoc | None = None,
    probe_prior: Mapping[str, ProbePriorDoc] | None = None,
    run_periods_s: Iterable[float] = RUN_PERIODS_S,
) -> str:
    """The model file text for ``model``; ``signals`` maps each signal name to its unit.

    The file carries the difference equations ``compd run`` steps at each of
    ``run_periods_s`` and at the model's own sample time, where running there
    needs a conversion (:func:`compd.files.equations.derived_sets`: scipy).

    When ``signals`` is given it must name every signal the model reads (the
    schema requires declared signals to cover all uses). ``residuals`` gives,
    per output with a residual model, its block (sidecar file and sha256).
    """
    residuals = residuals or {}
    for output in model.outputs:
        if (output.residual is None) != (output.name not in residuals):
            raise ValueError(f"output {output.name!r}: residual model and its block must match")
    if signals is not None:
        missing = [name for name in model.signals() if name not in signals]
        if missing:
            raise ValueError(f"signals {missing} are used by the model but have no unit")
    has_discrete = any(
        isinstance(sub.tf, DiscreteTF) for output in model.outputs for sub in output.submodels
    )
    lines = [
        "# compd model file (see config/README.md for the schema).",
    ]
    if has_discrete:
        lines += [
            "# Discrete TFs: coefficients in ascending powers of z^-1 (Horejs 2015 eq. 1),",
            "#   a0 y(k) = b0 u(k-nk) + b1 u(k-nk-1) + ... - a1 y(k-1) - ...",
            "# printed at full precision: slow poles make the static gain B(1)/A(1)",
            "# sensitive to the last digits, so do not round them.",
        ]
    lines += [
        f"schema: {SCHEMA}",
        f"name: {_string(model.name)}",
    ]
    if description:
        lines.append(f"description: {_string(description)}")
    lines.append(f"sample_time_s: {yaml_float(model.sample_time_s)}")
    if signals is not None:
        lines.append("signals:")
        for name, unit in signals.items():
            lines.append(f"  {_string(name)}: {{unit: {_string(unit)}}}")
    if model.ambient is not None:
        moves = ", ".join(_string(name) for name in model.ambient.moves)
        lines += [
            "# the thermal zero follows the shop air: at start the fixed references of the inputs",
            "# it moves are shifted by how far this signal is from its reference (the calibration's)",
            f"ambient: {{signal: {_string(model.ambient.signal)}, "
            f"reference: {yaml_float(model.ambient.reference)}, moves: [{moves}]}}",
        ]
    lines.append("outputs:")
    for output in model.outputs:
        lines += [f"  {_string(output.name)}:", "    unit: um"]
        if output.bias_um:
            lines.append(
                f"    bias_um: {yaml_float(output.bias_um)}  # a constant added to the output"
            )
        lines.append("    submodels:")
        for sub in output.submodels:
            if sub.position is not None:
                lines.append(
                    "      # slope term (Pahk 2002 m1(T) * P): this TF is in um per mm, multiplied by "
                    "the position minus reference_mm"
                )
            if sub.gate is not None and sub.gate.target.value == "input":
                lines.append(
                    "      # gated input: when the gate closes this contribution decays "
                    "with the TF's time constants"
                )
            lines += _submodel(sub)
        if output.name in residuals:
            lines += _residual(residuals[output.name])
    lines += equations_lines(model, derived_sets(model, run_periods_s))
    if consistency is not None:
        lines += consistency_lines(consistency)
    if probe_prior:
        lines += probe_prior_lines(probe_prior)
    if provenance is not None:
        lines += provenance_lines(provenance)
    return "\n".join(lines) + "\n"


def consistency_lines(doc: ConsistencyDoc) -> list[str]:
    """The ``consistency:`` block: how each input follows the others (the daemon's plausibility check)."""
    lines = [
        "# each input predicted from the other logged signals (compd.model.consistency): the daemon",
        "# checks every reading against it and stands in with the prediction while a sensor is wrong",
        "consistency:",
        f"  signals: [{', '.join(_string(n) for n in doc.signals)}]",
        f"  checked: [{', '.join(_string(n) for n in doc.checked)}]",
        f"  taus_s: {_numbers(doc.taus_s)}",
        f"  heated: [{', '.join(_string(n) for n in doc.heated)}]",
    ]
    for key in ("sigma", "max_rate_per_s"):
        values: dict[str, float] = getattr(doc, key)
        lines.append(
            f"  {key}: {{{', '.join(f'{_string(k)}: {yaml_float(v)}' for k, v in values.items())}}}"
        )
    for key in ("mean", "low", "high"):
        lines.append(f"  {key}: {_numbers(getattr(doc, key))}")
    lines.append("  covariance:  # 10 significant digits: ample for a ridge-regularised covariance")
    lines += [f"    - {_numbers(float(f'{v:.10g}') for v in row)}" for row in doc.covariance]
    return lines


def probe_prior_lines(docs: Mapping[str, ProbePriorDoc]) -> list[str]:
    """The ``probe_prior:`` block: per output, what the probe update starts from (compd.model.probeupdate)."""
    lines = [
        "# per output, the prior of the probe update (compd.model.probeupdate): each sub-model's",
        "# coefficient (its static gain, um per input unit; or its gain where no coefficients are",
        "# given) and a bias, the calibration's posterior widened by its residue's autocorrelation",
        "probe_prior:",
    ]
    for output, doc in docs.items():
        lines += [
            f"  {_string(output)}:",
            f"    parameters: [{', '.join(_string(n) for n in doc.parameters)}]",
            f"    residue_sigma_um: {yaml_float(doc.residue_sigma_um)}",
            f"    samples: {doc.samples}",
            f"    effective_samples: {yaml_float(doc.effective_samples)}",
            f"    output_peak_um: {yaml_float(doc.output_peak_um)}",
        ]
        if doc.coefficients is not None:
            lines.append(f"    coefficients: {_numbers(doc.coefficients)}")
        if doc.transient_variance_um2:
            lines.append(
                "    transient_variance_um2:  # per probe interval (s): what does not persist over it"
            )
            lines += [
                f"      {yaml_float(interval)}: {yaml_float(variance)}"
                for interval, variance in sorted(doc.transient_variance_um2.items())
            ]
        lines += [
            "    covariance:  # 10 significant digits",
        ]
        lines += [f"      - {_numbers(float(f'{v:.10g}') for v in row)}" for row in doc.covariance]
        if doc.gains_covariance is not None:
            lines.append("    gains_covariance:  # 10 significant digits")
            lines += [
                f"      - {_numbers(float(f'{v:.10g}') for v in row)}"
                for row in doc.gains_covariance
            ]
    return lines


def equations_lines(model: Model, sets: Sequence[DifferenceEquations]) -> list[str]:
    """The ``difference_equations:`` block for ``sets`` (no lines for none), sub-models in model order."""
    if not sets:
        return []
    lines = [
        "# each sub-model's TF as compd run steps it at a loop period, derived from the TFs above by",
        "# compd (zero-order hold; a discrete TF resampled exactly), ascending powers of z^-1: the",
        "# daemon runs these with numpy alone and converts nothing. tfs_sha256: of the TFs they come",
        "# from. 'compd model compile FILE --period-s P' adds a period",
        "difference_equations:",
    ]
    for equations in sorted(sets, key=lambda s: s.period_s):
        lines += [
            f"  - period_s: {yaml_float(equations.period_s)}",
            f'    tfs_sha256: "{equations.tfs_sha256}"',
            "    outputs:",
        ]
        for output in model.outputs:
            lines.append(f"      {_string(output.name)}:")
            for sub in output.submodels:
                tf = equations.tfs[(output.name, sub.name)]
                lines += [
                    f"        {_string(sub.name)}: {{nk: {tf.nk},",
                    f"          num: {_numbers(tf.num)},",
                    f"          den: {_numbers(tf.den)}}}",
                ]
    return lines
