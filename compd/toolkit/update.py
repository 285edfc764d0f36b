"""Post-process update of a model's named gains from sparse probe measurements (Post-process 2024).

In repetitive production the real TCP error is measured only now and then: a
touch probe at a tool change or when the technological conditions change.
``compd update`` takes a model, the logged signals of one run (DATA) and the
probe measurements taken during it (PROBES), and re-optimises the gains the
model file names (``gain_name: g1`` per sub-model, Post-process 2024 eq. 6) so that
the model matches the probes (eq. 8, default bounds eq. 9). Every sub-model's
TF stays as it was: only magnitudes change, so a model calibrated in one
configuration can follow another (a different spindle head, another position
in the workspace) without a new calibration.

The bridge between files and :mod:`compd.model.gains`: the model is run once
over DATA with every optimised gain at 1, each gain's contribution is
interpolated at the probe instants, and the optimiser works on those numbers
alone. With a continuously measured run (``--characteristic-from``), the
gains' characteristic bounds (eq. 7) are found first and bound the probe fit.

Probe files are read by :mod:`compd.toolkit.probes`, gain names resolved by
:mod:`compd.toolkit.gainsets`.
"""

from __future__ import annotations

import datetime as dt
import math
from dataclasses import dataclass

import numpy as np

from compd import __version__
from compd.errors import DataFileError, ModelError
from compd.files.data import DataSet
from compd.files.equations import kept_periods
from compd.files.modelfile import ModelFile, parse_model
from compd.files.modelschema import CharacteristicDoc, UpdateDoc
from compd.files.modelwriter import model_to_yaml
from compd.model.gains import (
    DEFAULT_BOUNDS,
    CharacteristicBounds,
    GainUpdate,
    characteristic_bounds,
    segments_between_changes,
    update_gains,
)
from compd.model.metrics import fit_percent
from compd.toolkit.derived import kept_priors, kept_residuals
from compd.toolkit.evaluate import InitialState
from compd.toolkit.gainsets import Decomposition, Gain, decompose, model_gains, with_gains
from compd.toolkit.probes import ProbeRows, Probes, probe_rows, probed_outputs
from compd.toolkit.zeroing import zero_displacements

#: Intervals between changes shorter than this are too short for eq. 7 to judge a gain.
MIN_SEGMENT_S = 300.0


@dataclass(frozen=True, eq=False)
class Characteristic:
    """Post-process 2024 eq. 7 on a continuous run: the per-interval optima and the bounds they give."""

    data: DataSet
    output: str
    segment_signal: str
    result: CharacteristicBounds
    decomposition: Decomposition


def find_characteristic(
    model_file: ModelFile,
    gains: list[Gain],
    data: DataSet,
    *,
    output: str,
    segment_signal: str,
    search_bounds: np.ndarray,
    seed: int,
    init: InitialState = "steady",
) -> Characteristic:
    """Optimise the gains on every interval of constant ``segment_signal`` of a measured run."""
    data, _ = zero_displacements(data, [output])
    measured = data.column(output)
    signal = data.column(segment_signal)
    decomposition = decompose(model_file, gains, data, init=init)
    min_samples = max(len(gains) + 1, math.ceil(MIN_SEGMENT_S / data.sample_time_s))
    segments = segments_between_changes(signal, min_samples=min_samples)
    try:
        result = characteristic_bounds(
            decomposition.contributions[output],
            measured,
            segments,
            search_bounds=search_bounds,
            fixed_um=decomposition.fixed[output],
            seed=seed,
        )
    except ModelError as exc:
        raise DataFileError(
            data.path,
            exc.message,
            where=f"column {segment_signal}",
            fix=f"Use a run in which {segment_signal} holds each value for at least "
            f"{MIN_SEGMENT_S:g} s",
        ) from exc
    return Characteristic(data, output, segment_signal, result, decomposition)


@dataclass(frozen=True, eq=False)
class Update:
    """A model with re-optimised gains, the evidence, and the file text to write."""

    parent: ModelFile
    updated: ModelFile
    yaml_text: str
    gains: list[Gain]
    bounds: np.ndarray
    result: GainUpdate
    rows: ProbeRows
    predicted_before_um: np.ndarray  # at the probe rows
    predicted_after_um: np.ndarray
    fit_before: dict[str, float]
    fit_after: dict[str, float]
    characteristic: Characteristic | None
    #: Fit % (before, after) on the continuous run of ``characteristic``.
    characteristic_fit: tuple[float, float] | None
    notes: tuple[str, ...]

    @property
    def gains_before(self) -> np.ndarray:
        return np.array([g.value for g in self.gains])


def update_model(
    parent: ModelFile,
    data: DataSet,
    probes: Probes,
    *,
    bounds: dict[str, tuple[float, float]] | None = None,
    output: str | None = None,
    continuous: DataSet | None = None,
    segment_signal: str = "spindle_speed_rpm",
    seed: int = 0,
    init: InitialState = "steady",
    command: str = "",
) -> Update:
    """Optimise ``parent``'s named gains on ``probes`` taken during ``data`` (Post-process 2024 eq. 8/9).

    With ``continuous`` (a run with the displacement measured throughout),
    the characteristic bounds of eq. 7 replace the default ``(0, 2)`` of every
    gain ``bounds`` does not set.
    """
    bounds = bounds or {}
    outputs = probed_outputs(parent, probes, output)
    gains = model_gains(parent, bounds, outputs)
    limits = np.array([bounds.get(g.key, DEFAULT_BOUNDS) for g in gains], dtype=float)
    notes: list[str] = []
    characteristic = None
    if continuous is not None:
        target = _one_measured(continuous, outputs)
        characteristic = find_characteristic(
            parent, gains, continuous, output=target, segment_signal=segment_signal,
            search_bounds=limits, seed=seed, init=init,
        )  # fmt: skip
        found = characteristic.result.bounds
        limits = np.array([limits[j] if g.key in bounds else found[j] for j, g in enumerate(gains)])
    decomposition = decompose(parent, gains, data, init=init)
    rows = probe_rows(decomposition, probes, outputs)
    before = np.array([g.value for g in gains])
    try:
        result = update_gains(
            rows.contributions_um, rows.measured_um, limits, seed=seed,
            fixed_at_probes=rows.fixed_um, initial_gains=before,
        )  # fmt: skip
    except ModelError as exc:
        raise DataFileError(probes.path, exc.message) from exc
    if not result.well_determined:
        notes.append(
            f"the probes determine only {result.rank} of {len(gains)} gains (their contributions "
            "are proportional at the probe instants): probe at other conditions too"
        )
    for gain, hit in zip(gains, result.at_bound, strict=True):
        if hit:
            notes.append(
                f"gain {gain.key} ends on a bound: the configuration may need a new sub-model "
                "rather than a gain (Post-process 2024 sect. 4)"
            )
    fit_before, fit_after = {}, {}
    judged, _ = zero_displacements(data, outputs)  # as compare judges the run
    for name in outputs:
        if judged.has(name):
            measured = judged.column(name)
            fit_before[name] = fit_percent(measured, decomposition.predicted(name, before))
            fit_after[name] = fit_percent(measured, decomposition.predicted(name, result.gains))
    characteristic_fit = None
    if characteristic is not None:
        # The continuous run is a second record to judge the new gains on.
        name, measured = characteristic.output, characteristic.data.column(characteristic.output)
        characteristic_fit = (
            fit_percent(measured, characteristic.decomposition.predicted(name, before)),
            fit_percent(measured, characteristic.decomposition.predicted(name, result.gains)),
        )
    model = with_gains(parent.model, gains, result.gains)
    record = UpdateDoc(
        parent_sha256=parent.sha256,
        data=data.path,
        probes=probes.path,
        probe_times_s=[float(t) for t in probes.time_s],
        probe_values_um={
            name: [None if math.isnan(v) else float(v) for v in probes.values[name]]
            for name in outputs
        },
        bounds={g.key: (float(lo), float(hi)) for g, (lo, hi) in zip(gains, limits, strict=True)},
        characteristic=None
        if characteristic is None
        else CharacteristicDoc(
            data=characteristic.data.path,
            segment_signal=segment_signal,
            segments=len(characteristic.result.segments),
            bounds={
                g.key: (float(lo), float(hi))
                for g, (lo, hi) in zip(gains, characteristic.result.bounds, strict=True)
            },
            fit_percent_before=_finite(characteristic_fit[0]) if characteristic_fit else None,
            fit_percent_after=_finite(characteristic_fit[1]) if characteristic_fit else None,
        ),
        gains_before={g.key: g.value for g in gains},
        gains_after={g.key: float(v) for g, v in zip(gains, result.gains, strict=True)},
        probe_rms_before_um=_finite(result.rms_before_um),
        probe_rms_after_um=_finite(result.rms_after_um),
        fit_percent_before={k: v for k, v in fit_before.items() if math.isfinite(v)},
        fit_percent_after={k: v for k, v in fit_after.items() if math.isfinite(v)},
        seed=seed,
        created=dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
    )
    doc = parent.doc
    provenance = doc.provenance.model_copy(
        update={
            "updates": [*doc.provenance.updates, record],
            "compd_version": __version__,
            "command": command or doc.provenance.command,
        }
    )
    priors, prior_notes = kept_priors(parent, model)
    notes += prior_notes
    text = model_to_yaml(
        model,
        description=doc.description,
        signals=parent.signal_units(),
        provenance=provenance,
        residuals=kept_residuals(parent),
        consistency=doc.consistency,
        probe_prior=priors,
        run_periods_s=kept_periods(doc.difference_equations),
    )
    updated = parse_model(text, parent.path)  # beside the parent, where its forests' sidecars are
    return Update(
        parent=parent,
        updated=updated,
        yaml_text=text,
        gains=gains,
        bounds=limits,
        result=result,
        rows=rows,
        predicted_before_um=rows.fixed_um + rows.contributions_um @ before,
        predicted_after_um=rows.fixed_um + rows.contributions_um @ result.gains,
        fit_before=fit_before,
        fit_after=fit_after,
        characteristic=characteristic,
        characteristic_fit=characteristic_fit,
        notes=tuple(notes),
    )


def _one_measured(data: DataSet, outputs: list[str]) -> str:
    measured = [name for name in outputs if data.has(name)]
    if len(measured) != 1:
        raise DataFileError(
            data.path,
            f"characteristic bounds need one measured output column, found {measured or 'none'} "
            f"of {', '.join(outputs)}",
            fix="Pass --output to choose the axis, in a run that measured it continuously",
        )
    return measured[0]


def _finite(value: float) -> float | None:
    return value if math.isfinite(value) else None
