"""Fitting a model file to a calibration data file: columns in, ``compd.model/1`` model out.

The bridge between files and :func:`compd.model.identify.identify`: takes
the named columns as changes from their first value (the convention
``compd compare`` runs models with, so the fit % printed here is the one
compare reproduces), turns the phase-gate column into a gate, builds the
:class:`~compd.model.structure.Model` and its provenance (the calibration
data's fit, residue RMS and the range of every column, which compare uses to
flag operating conditions the model never saw).
"""

from __future__ import annotations

import datetime as dt
import re
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from compd import __version__
from compd.data import DataSet
from compd.errors import DataFileError, ModelError
from compd.model.identify import MAX_ORDER, METHODS, Identification, Method, Progress, identify
from compd.model.metrics import Comparison
from compd.model.structure import Gate, GateTarget, InputSpec, Model, Output, SubModel
from compd.modelfile import CalibrationDoc, ProvenanceDoc
from compd.modelwriter import model_to_yaml

#: Unit suffixes of compd's signal naming convention (``T_spindle_degC``, ``spindle_power_kw``).
_UNIT_SUFFIX = re.compile(r"_(degC|K|rpm|kw|kW|W|um|mm|s|bar|percent|pct)$")


@dataclass(frozen=True, eq=False)
class FitResult:
    """A fitted model, how it was made and how well it simulates its calibration data."""

    identification: Identification
    model: Model
    provenance: ProvenanceDoc
    comparison: Comparison
    yaml_text: str


def unit_of(name: str) -> str:
    """The unit a signal's name carries (``T_spindle_degC`` -> ``degC``), or ``-`` if it carries none."""
    match = _UNIT_SUFFIX.search(name)
    if match is None:
        return "-"
    return {"kw": "kW", "pct": "percent"}.get(match.group(1), match.group(1))


def identification_to_model(
    identification: Identification,
    *,
    output: str,
    name: str,
    gate_signal: str | None = None,
) -> Model:
    """One output ``output`` whose sub-models are the identified channels (inputs referenced to start).

    Gated channels get ``gate: {signal: gate_signal, above: 0, applies_to: input}``
    (see :mod:`compd.model.identify` for why the input, not the output). With a
    phase gate the cooling sub-models share the gain ``g1`` and the
    heating-difference ones ``g2`` (seed 002 eq. 6), so ``compd update`` can
    re-weigh the two phases from probe measurements.
    """
    method = identification.method
    subs = []
    for channel in identification.channels:
        if channel.gated:
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
        else:
            effect = (
                f"{channel.input_name}: cooling, always on ({method})"
                if gate_signal is not None
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


def _check_arguments(
    data: DataSet, output: str, inputs: Sequence[str], order: int | str, method: str
) -> None:
    if not inputs:
        raise DataFileError(
            data.path,
            "no inputs given",
            where="--inputs",
            fix=f"Name one or more columns, comma-separated, from: {', '.join(data.columns)}",
        )
    repeated = sorted({i for i in inputs if list(inputs).count(i) > 1})
    if repeated:
        raise DataFileError(
            data.path, f"inputs {repeated} are named twice", where="--inputs", fix="Name each once"
        )
    if output in inputs:
        raise DataFileError(
            data.path,
            f"the output column {output!r} is also among the inputs",
            where="--inputs",
            fix="A model cannot use the displacement it predicts; remove it from --inputs",
        )
    for column in (output, *inputs):
        data.column(column)  # an unknown column names the file's columns
    if order != "auto" and not (isinstance(order, int) and 1 <= order <= MAX_ORDER):
        raise DataFileError(
            data.path,
            f"order must be 'auto' or 1..{MAX_ORDER}, got {order!r}",
            where="--order",
            fix="Use --order auto to choose it on held-back data",
        )
    if method not in METHODS:
        raise DataFileError(
            data.path, f"unknown method {method!r}", where="--method", fix=f"Use one of {METHODS}"
        )
    for column in inputs:
        if np.ptp(data.column(column)) == 0.0:
            raise DataFileError(
                data.path,
                f"input column {column!r} is constant ({data.column(column)[0]:g}) over the whole "
                "record, so its effect cannot be identified",
                where=f"column {column!r}",
                fix="Leave it out of --inputs, or calibrate on data in which it varies",
            )


def fit_data(
    data: DataSet,
    *,
    output: str,
    inputs: Sequence[str],
    method: Method = "oe",
    order: int | str = "auto",
    phase_gate: str | None = None,
    name: str | None = None,
    command: str | None = None,
    progress: Progress | None = None,
) -> FitResult:
    """Identify ``output`` from ``inputs`` (columns of ``data``) and build the model file.

    Raises :class:`~compd.errors.DataFileError` (naming the file, the option or
    column, and the fix) for bad arguments and for data the method cannot fit.
    """
    _check_arguments(data, output, inputs, order, method)
    y = data.column(output)
    changes = {column: data.column(column) - data.column(column)[0] for column in inputs}
    gate = None
    if phase_gate is not None:
        gate = data.column(phase_gate) > 0.0
    try:
        identification = identify(
            y,
            changes,
            sample_time_s=data.sample_time_s,
            method=method,
            order="auto" if order == "auto" else int(order),
            gate=gate,
            progress=progress,
        )
    except ModelError as exc:
        where = f"--phase-gate {phase_gate}" if "phase-gate" in exc.message else ""
        raise DataFileError(data.path, exc.message, where=where) from exc
    model = identification_to_model(
        identification,
        output=output,
        name=name or f"{output}-{method}",
        gate_signal=phase_gate,
    )
    comparison = Comparison.of(output, y, identification.simulated_um)
    provenance = _provenance(data, identification, comparison, command, phase_gate)
    signals = {signal: unit_of(signal) for signal in model.signals()}
    text = model_to_yaml(
        model,
        description=f"{output} from {', '.join(inputs)}, identified by compd fit --method {method}",
        signals=signals,
        provenance=provenance,
    )
    return FitResult(identification, model, provenance, comparison, text)


def _provenance(
    data: DataSet,
    identification: Identification,
    comparison: Comparison,
    command: str | None,
    phase_gate: str | None,
) -> ProvenanceDoc:
    output = comparison.output
    orders = identification.orders
    notes = [
        f"free-run simulation fit {identification.fit_percent:.4f} % on the whole calibration "
        "record (inputs as changes from start, model started at rest)",
    ]
    if identification.validation_fit_percent is not None:
        notes.append(
            f"orders chosen automatically: fit {identification.validation_fit_percent:.4f} % "
            "on the held-back last third, estimated on the first two thirds"
        )
    notes.append(
        f"orders: na={orders.na} nb={list(orders.nb)} nf={list(orders.nf)} nk={list(orders.nk)}"
    )
    if phase_gate is not None:
        notes.append(
            f"phase gate {phase_gate} > 0 switches the heating-difference TFs' inputs "
            "(seed 002 eq. 5 switches their outputs; see compd.model.identify)"
        )
    ranges = {
        column: (float(np.min(values)), float(np.max(values)))
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
            samples=len(data),
            sample_time_s=data.sample_time_s,
            fit_percent={output: identification.fit_percent},
            rms_um={output: comparison.residue.rms_um},
            ranges=ranges,
        ),
        notes="; ".join(notes),
    )
