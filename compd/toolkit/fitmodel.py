"""What ``compd fit`` writes: sub-models named for their channels, signal units, provenance.

An :class:`~compd.model.identify.Identification` becomes a
:class:`~compd.model.structure.Model` (one output, one sub-model per channel,
phase-gate gains ``g1``/``g2``, slope sub-models for a position) and the
provenance recorded with it: the calibration data's fit, residue RMS and the
range of every column, which ``compd compare`` uses to flag operating
conditions the model never saw.
"""

from __future__ import annotations

import datetime as dt
import re
from collections.abc import Mapping
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from compd import __version__
from compd.errors import ModelError
from compd.files.columns import UNIT_PREFIX
from compd.files.effects import load_catalogue
from compd.files.modelschema import CalibrationDoc, ProvenanceDoc
from compd.model.lagbank import lag_name
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
from compd.toolkit.methods import writes_lags

# Types only: unit_of is wanted where the data reader (pandas) and the
# identification stack (scipy.signal) are not (compd.toolkit.residual).
if TYPE_CHECKING:
    from compd.files.data import DataSet
    from compd.model.identify import Identification
    from compd.model.metrics import Comparison
    from compd.toolkit.span import Span

#: Unit suffixes of compd's signal naming convention (``T_spindle_degC``, ``spindle_power_kw``).
_UNIT_SUFFIX = re.compile(r"_(degC|K|rpm|kw|kW|W|um|mm|s|bar|percent|pct)$")


def unit_of(name: str) -> str:
    """The unit a signal's name carries (``T_spindle_degC`` -> ``degC``), or ``-`` if it carries none."""
    match = _UNIT_SUFFIX.search(name)
    if match is None:
        return "-"
    return {"kw": "kW", "pct": "percent"}.get(match.group(1), match.group(1))


def column_unit(data: DataSet, name: str) -> str:
    """A column's unit: as the file records it (compd's recorder writes ``unit.<column>``, the
    config's unit), else as its name carries it (:func:`unit_of`)."""
    return data.metadata.get(UNIT_PREFIX + name) or unit_of(name)


def identification_to_model(
    identification: Identification,
    *,
    output: str,
    name: str,
    gate_signal: str | None = None,
    position: Position | None = None,
) -> Model:
    """One output ``output`` whose sub-models are the identified channels (inputs referenced to start).

    Gated channels get ``gate: {signal: gate_signal, above: 0, applies_to: input}``
    (see :mod:`compd.model.identify` for why the input, not the output). With a
    phase gate the cooling sub-models share the gain ``g1`` and the
    heating-difference ones ``g2`` (Post-process 2024 eq. 6), so ``compd update`` can
    re-weigh the two phases from probe measurements. Slope channels (seed
    003 ``m1``) get ``position`` and are named ``INPUT_slope``.
    """
    method = identification.method
    subs = []
    for channel in identification.channels:
        if channel.sloped:
            if position is None:
                raise ModelError("a slope channel needs the position signal")
            subs.append(
                SubModel(
                    name=f"{channel.input_name}_slope",
                    effect=f"{channel.input_name}: slope in um per mm, times "
                    f"({position.signal} - {position.reference_mm:g} mm) ({method})",
                    input=InputSpec(channel.input_name),
                    tf=channel.tf,
                    position=position,
                )
            )
        elif channel.gated:
            if gate_signal is None:
                raise ModelError("a gated channel needs the gate signal's name")
            subs.append(
                SubModel(
                    name=f"{channel.input_name}_heating",
                    effect=f"{channel.input_name}: heating minus cooling, while "
                    f"{gate_signal} > 0 ({method})",
                    input=InputSpec(channel.input_name),
                    tf=channel.tf,
                    gate=Gate(gate_signal, 0.0, True, GateTarget.INPUT),
                    gain_name="g2",
                )
            )
        elif channel.time_constant_s is not None:
            tau = channel.time_constant_s
            subs.append(
                SubModel(
                    name=lag_name(channel.input_name, tau),
                    effect=f"{channel.input_name}: first-order lag of {tau:g} s (lagbank)"
                    if tau
                    else f"{channel.input_name}: static gain (lagbank)",
                    input=InputSpec(channel.input_name),
                    tf=channel.tf,
                )
            )
        else:
            effect = (
                f"{channel.input_name}: cooling, always on ({method})"
                if gate_signal is not None
                else f"{channel.input_name}: offset at every position ({method})"
                if position is not None
                else f"{channel.input_name} ({method})"
            )
            subs.append(
                SubModel(
                    name=channel.input_name,
                    effect=effect,
                    input=InputSpec(channel.input_name),
                    tf=channel.tf,
                    gain_name=None if gate_signal is None else "g1",
                )
            )
    return Model(name, identification.sample_time_s, (Output(output, tuple(subs)),))


def with_references(
    model: Model, references: Mapping[str, float], units: Mapping[str, str] | None = None
) -> Model:
    """``model`` with each input's reference fixed at ``references[signal]`` (its thermal zero).

    The fit takes inputs as changes from the calibration's first values; the
    model file keeps those values, so a daemon started on a warm machine (or
    without its saved state) still counts the drift from the calibration's
    zero instead of from its own start. Inputs with a ``minus`` signal keep theirs.
    An input the effect catalogue calls the shop air (``T_ambient*``, ...) becomes
    the model's :class:`~compd.model.structure.AmbientZero`: a cold machine is in
    equilibrium with today's air, not the calibration day's, so the zero follows it.
    ``units``: each input's unit where the data records it (else its name's).
    """
    catalogue = load_catalogue()
    air = [name for name in references if catalogue.effect_for(name).startswith("ambient")]
    outputs = tuple(
        replace(
            output,
            submodels=tuple(
                replace(sub, input=replace(sub.input, reference=float(references[name])))
                if (name := sub.input.signal) in references and sub.input.minus is None
                else sub
                for sub in output.submodels
            ),
        )
        for output in model.outputs
    )
    unit = (units or {}).get
    temperatures = tuple(n for n in references if (unit(n) or unit_of(n)) in ("degC", "K"))
    ambient = AmbientZero(air[0], float(references[air[0]]), temperatures) if air else None
    return replace(model, outputs=outputs, ambient=ambient)


def describe_references(model: Model, references: Mapping[str, float]) -> str:
    """The provenance note on the thermal zero a fitted model's references hold."""
    values = ", ".join(f"{name} {value:.4g}" for name, value in references.items())
    moved = (
        ""
        if model.ambient is None
        else f"; those of {', '.join(model.ambient.moves)} shifted at start by "
        f"{model.ambient.signal}'s change from its own (a cold machine is at the shop's temperature)"
    )
    return (
        f"input references (the thermal zero the daemon counts drift from): the calibration's "
        f"first values, {values}{moved}"
    )


def fit_provenance(
    data: DataSet,
    identification: Identification,
    comparison: Comparison,
    command: str | None,
    phase_gate: str | None,
    position: Position | None = None,
    span: Span | None = None,
) -> ProvenanceDoc:
    """The provenance of a fitted model: how it was fitted, on what, and how well (notes say why)."""
    output = comparison.output
    orders = identification.orders
    first = 0 if span is None else span.start
    notes = [
        f"free-run simulation fit {identification.fit_percent:.4f} % on the whole calibration "
        "record (inputs as changes from start, model started at rest)"
        if span is None or span.whole
        else f"free-run simulation fit {identification.fit_percent:.4f} % "
        f"{span.describe('fitted')} (inputs as changes from the file's first values, model "
        "started at rest there)",
    ]
    if identification.validation_fit_percent is not None:
        notes.append(
            f"orders chosen automatically: fit {identification.validation_fit_percent:.4f} % "
            "on the held-back last third, estimated on the first two thirds"
        )
    if not writes_lags(identification.method):  # all first-order lags: said below
        notes.append(
            f"orders: na={orders.na} nb={list(orders.nb)} nf={list(orders.nf)} nk={list(orders.nk)}"
        )
    if phase_gate is not None:
        notes.append(
            f"phase gate {phase_gate} > 0 switches the heating-difference TFs' inputs "
            "(Post-process 2024 eq. 5 switches their outputs; see compd.model.identify)"
        )
    if position is not None:
        notes.append(
            f"slope sub-models are multiplied by ({position.signal} - {position.reference_mm:g} "
            "mm) after their TF; their numerators were refitted in that form (see "
            "compd.model.position)"
        )
    ranges = {  # of the samples fitted: the conditions the model was fitted for
        column: (float(np.min(values[first:])), float(np.max(values[first:])))
        for column, values in data.columns.items()
    }
    return ProvenanceDoc(
        data=data.path,
        command=command,
        created=dt.datetime.now(dt.UTC).replace(microsecond=0).isoformat().replace("+00:00", "Z"),
        compd_version=__version__,
        method=identification.method,
        fit_percent={output: identification.fit_percent},
        calibration=CalibrationDoc(
            data=data.path,
            samples=len(data) - first,
            sample_time_s=data.sample_time_s,
            fit_percent={output: identification.fit_percent},
            rms_um={output: comparison.residue.rms_um},
            ranges=ranges,
        ),
        notes="; ".join(notes),
    )
