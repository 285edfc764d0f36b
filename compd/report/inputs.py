"""Per-input view of a model output: static gain, its standard error, time constants, step response.

A lag bank gives one input four or five sub-models of "gain 1 / always";
a reader wants one row per input (as MATLAB's ``step`` and ``tfest``
report): the output's change per unit step of it, how fast, how sure. Inputs
are grouped by what multiplies the TF: the input (signal minus signal), the
gate and the position factor (a slope term's gain is um per mm per unit).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from compd.model import stepresponse
from compd.model.transfer import DiscreteTF
from compd.report.gather import ModelRun


@dataclass(frozen=True, eq=False)
class InputResponse:
    """One input of one output, all its sub-models summed."""

    label: str
    """The input as the model reads it (``T_spindle_degC``, ``T_a - T_b``)."""
    factors: str
    """Gate and position factors, or ``always``."""
    submodels: tuple[str, ...]
    static_gain: float
    """Output units (um) per unit of the input (um/mm per unit for a position term)."""
    standard_error: float
    """Of ``static_gain`` on the report's record (see :func:`stepresponse.gain_check`); NaN: none."""
    record_factor: float
    """The scale on this input's contribution the report's record fits best (1: it agrees)."""
    time_constants_s: tuple[float, ...]
    """The dominant ones, by the weight of their sub-model in the static gain."""
    time_s: np.ndarray
    step_um: np.ndarray


def input_responses(run: ModelRun, output: str) -> tuple[InputResponse, ...]:
    """The inputs of ``output`` in ``run``'s model, in the order their first sub-model appears."""
    return inputs_and_check(run, output)[0]


def inputs_and_check(
    run: ModelRun, output: str
) -> tuple[tuple[InputResponse, ...], stepresponse.GainCheck | None]:
    """:func:`input_responses` and how the report's record judges their gains (None: no inputs)."""
    compiled = run.evaluation.compiled
    row = compiled.output_matrix[compiled.output_names.index(output)]
    groups: dict[tuple[str, str], list[int]] = {}
    for i in np.flatnonzero(row):
        sub = compiled.submodels[int(i)]
        text = (
            sub.input.signal
            if sub.input.minus is None
            else f"{sub.input.signal} - {sub.input.minus}"
        )
        groups.setdefault((text, sub.describe_factors()), []).append(int(i))
    if not groups:
        return (), None
    result = run.evaluation.result
    columns = np.column_stack([result.contributions[:, idx].sum(axis=1) for idx in groups.values()])
    measured = run.evaluation.data.column(run.outputs[output].measured_column)
    fixed = run.evaluation.predicted(output) - columns.sum(axis=1)  # e.g. a residual forest
    check = stepresponse.gain_check(columns, measured - fixed)
    ts = compiled.sample_time_s
    found = []
    for ((label, factors), idx), rel, factor in zip(
        groups.items(), check.relative_errors, check.factors, strict=True
    ):
        tfs: list[DiscreteTF] = [compiled.discrete[i] for i in idx]
        gains = [float(compiled.gain[i]) for i in idx]
        gain = stepresponse.static_gain(tfs, gains)
        time_s, step = stepresponse.step_response(tfs, gains, ts)
        found.append(
            InputResponse(
                label=label,
                factors=factors,
                submodels=tuple(compiled.submodels[i].name for i in idx),
                static_gain=gain,
                standard_error=abs(gain) * float(rel),
                record_factor=float(factor),
                time_constants_s=stepresponse.dominant_time_constants_s(tfs, gains, ts),
                time_s=time_s,
                step_um=step,
            )
        )
    return tuple(found), check
