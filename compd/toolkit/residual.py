"""Fitting Swiss-lathe paper's residual model and storing its forest beside the model file.

``compd fit --residual-model door_open`` fits the TF model as usual, then a
scikit-learn ``RandomForestRegressor`` (seeded; squared error, bootstrapped
trees as in Swiss-lathe paper sect. 2.3) on the TF model's free-run residue against
the smoothed door features of :mod:`compd.model.residual`. The fitted trees
are exported to plain arrays (children, feature, threshold, value) and never
pickled: a sidecar ``.npz`` next to the model YAML holds them, named in the
YAML with its sha256, which :func:`~compd.files.sidecar.load_sidecar` checks, so a model file and
its forest cannot be mixed up. The residue is judged as in Swiss-lathe paper
(tables 2-5): peak-to-peak and RMS of measured minus predicted, TF alone
vs stacked.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from compd.errors import DataFileError, ModelError, ModelFileError
from compd.files.equations import kept_periods
from compd.files.modelfile import ModelFile, parse_model
from compd.files.modelschema import ModelDoc, ResidualDoc, ResidualFiguresDoc
from compd.files.modelwriter import model_to_yaml
from compd.files.sidecar import FOREST_ARRAYS, sidecar_bytes, sidecar_path
from compd.model.residual import DEFAULT_TIME_CONSTANTS_S, DoorFeatures, Forest, ResidualModel
from compd.model.structure import Model
from compd.toolkit.evaluate import evaluate, measured_columns
from compd.toolkit.span import Span, until_stop

# compd.toolkit.fit imports the data and identification stack; only its types here
if TYPE_CHECKING:
    from compd.files.data import DataSet
    from compd.toolkit.fit import FitResult


def forest_from_sklearn(regressor: Any) -> Forest:
    """The fitted trees of a ``RandomForestRegressor`` (single output) as one flat node table."""
    trees = [estimator.tree_ for estimator in regressor.estimators_]
    offsets = np.cumsum([0] + [tree.node_count for tree in trees])
    parts: dict[str, list[np.ndarray]] = {name: [] for name in FOREST_ARRAYS[1:]}
    for offset, tree in zip(offsets[:-1], trees, strict=True):
        nodes = np.arange(tree.node_count)
        leaf = tree.children_left < 0
        parts["left"].append(np.where(leaf, nodes, tree.children_left) + offset)
        parts["right"].append(np.where(leaf, nodes, tree.children_right) + offset)
        parts["feature"].append(np.where(leaf, 0, tree.feature))
        parts["threshold"].append(np.where(leaf, 0.0, tree.threshold))
        parts["value"].append(tree.value[:, 0, 0].astype(float))
    joined = {name: np.concatenate(values) for name, values in parts.items()}
    return Forest(
        roots=offsets[:-1].astype(np.intp),
        left=joined["left"].astype(np.intp),
        right=joined["right"].astype(np.intp),
        feature=joined["feature"].astype(np.intp),
        threshold=joined["threshold"].astype(float),
        value=joined["value"],
        n_features=int(regressor.n_features_in_),
    )


@dataclass(frozen=True)
class ResidueFigures:
    """Swiss-lathe paper's figures of merit for one residue (um): peak-to-peak and RMS."""

    peak_to_peak_um: float
    rms_um: float

    @classmethod
    def of(cls, residue_um: np.ndarray) -> ResidueFigures:
        residue_um = np.asarray(residue_um, dtype=float)
        return cls(float(np.ptp(residue_um)), float(np.sqrt(np.mean(residue_um**2))))


@dataclass(frozen=True, eq=False)
class ResidualFit:
    """A forest fitted on a TF model's residue, with the residue before and after stacking."""

    residual: ResidualModel
    tf_alone: ResidueFigures
    stacked: ResidueFigures


def check_door_signal(path: str | Path, values: np.ndarray, signal: str, threshold: float) -> None:
    """Refuse a calibration record in which the door never changes state (file, column, fix)."""
    door = np.asarray(values) > threshold
    if door.all() or not door.any():
        raise DataFileError(
            path,
            f"column {signal!r} never changes state (always {'open' if door.all() else 'shut'}, "
            f"> {threshold:g} is open), so there is no door effect to learn",
            where=f"--residual-model {signal}",
            fix="Calibrate on a record with door openings (e.g. compd twin --scenario door), "
            "or fit without --residual-model",
        )


def fit_residual(
    residue_um: np.ndarray,
    door: np.ndarray,
    *,
    signal: str,
    sample_time_s: float,
    trees: int = 100,
    max_depth: int = 10,
    seed: int = 0,
    time_constants_s: tuple[float, ...] = DEFAULT_TIME_CONSTANTS_S,
    min_samples_leaf: int = 5,
    first_sample: int = 0,
) -> ResidualFit:
    """Fit ``RandomForestRegressor(trees, max_depth)`` of ``residue_um`` on the door features.

    The features are computed causally from a settled door at the first
    sample, as the model runs them from a steady start; only samples from
    ``first_sample`` on are fitted and judged (``--from``).
    """
    # scikit-learn only to fit, never to run; it ships no type information.
    from sklearn.ensemble import RandomForestRegressor  # type: ignore[import-untyped]

    if trees < 1 or max_depth < 1:
        raise ModelError(f"--trees and --max-depth must be >= 1, got {trees} and {max_depth}")
    features = DoorFeatures(signal, tuple(float(t) for t in time_constants_s))
    x, _ = features.record(door, sample_time_s, features.initial_state(door[0]))
    x, residue_um = x[first_sample:], residue_um[first_sample:]
    regressor = RandomForestRegressor(
        n_estimators=trees,
        max_depth=max_depth,
        min_samples_leaf=min_samples_leaf,
        random_state=seed,
        n_jobs=1,
    )
    regressor.fit(x, residue_um)
    residual = ResidualModel(features, forest_from_sklearn(regressor))
    stacked = residue_um - residual.forest.predict(x)
    return ResidualFit(residual, ResidueFigures.of(residue_um), ResidueFigures.of(stacked))


@dataclass(frozen=True, eq=False)
class StackedFit:
    """A fitted TF model with a residual forest: the model file text and its sidecar bytes."""

    model: Model
    fit: ResidualFit
    yaml_text: str
    sidecar_name: str
    sidecar: bytes


def stack_residual(
    result: FitResult,
    data: DataSet,
    model_path: str | Path,
    *,
    signal: str,
    trees: int = 100,
    max_depth: int = 10,
    seed: int = 0,
    span: Span | None = None,
) -> StackedFit:
    """Fit a door residual forest on ``result``'s calibration residue and build the stacked model file.

    ``model_path`` is where the YAML will be written; the sidecar goes beside
    it (:func:`sidecar_path`) and the YAML names it with its sha256.
    """
    # The model as written (with whatever compd fit baked into it), so the
    # residue is the one compare will show for it.
    written = parse_model(result.yaml_text, model_path)
    return stack_on_model(
        written,
        data,
        model_path,
        signal=signal,
        output=result.comparison.output,
        trees=trees,
        max_depth=max_depth,
        seed=seed,
        span=span,
    )


def stack_on_model(
    model_file: ModelFile,
    data: DataSet,
    model_path: str | Path,
    *,
    signal: str,
    output: str | None = None,
    trees: int = 100,
    max_depth: int = 10,
    seed: int = 0,
    span: Span | None = None,
) -> StackedFit:
    """Stack a door residual forest on an existing model, fitted on its free-run residue over ``data``.

    The model's sub-models are kept as they are (Swiss-lathe paper keeps its ARX and
    adds the forest); the residue is the one ``compd compare`` shows. With
    ``span`` the model and the door features run from the record's start and
    the forest is fitted on the span's samples.
    """
    if span is not None:
        data = until_stop(data, span)
    evaluation = evaluate(model_file, data, as_logged=span is not None and span.start > 0)
    data = evaluation.data  # its measured displacement as judged (compd.toolkit.zeroing)
    (predicted, measured), *others = measured_columns(evaluation, output).items()
    if others:
        raise DataFileError(
            data.path,
            f"the model has several outputs with columns in the file: {[predicted, *others]}",
            where="--output",
            fix="Name the one the residual model is for with --output",
        )
    base = model_file.model
    stacked = [o.name for o in base.outputs if o.residual is not None]
    if stacked:
        raise ModelFileError(
            model_file.path,
            f"output(s) {stacked} already have a residual model",
            where=f"outputs.{stacked[0]}.residual",
            fix="Stack on the model it was built from, or refit",
        )
    if not np.isclose(base.sample_time_s, data.sample_time_s, rtol=1e-9, atol=0.0):
        raise DataFileError(
            data.path,
            f"the model runs at {base.sample_time_s:g} s and the data at {data.sample_time_s:g} s",
            fix="Resample the data to the model's sample time (compd fit writes it at the data's)",
        )
    units = model_file.signal_units() or {}
    return _stack(
        base,
        model_file.doc,
        data.column(measured) - evaluation.predicted(predicted),
        data,
        model_path,
        output=predicted,
        description=model_file.doc.description or base.name,
        units=units,
        options=(signal, trees, max_depth, seed),
        span=span,
    )


def _stack(
    base: Model,
    parent: ModelDoc,
    residue: np.ndarray,
    data: DataSet,
    model_path: str | Path,
    *,
    output: str,
    description: str,
    units: Mapping[str, str],
    options: tuple[str, int, int, int],
    span: Span | None = None,
) -> StackedFit:
    from compd.toolkit.fitmodel import column_unit

    signal, trees, max_depth, seed = options
    door = data.column(signal)  # an unknown column names the file's columns
    check_door_signal(data.path, door, signal, 0.5)
    fit = fit_residual(
        residue,
        door,
        signal=signal,
        sample_time_s=data.sample_time_s,
        trees=trees,
        max_depth=max_depth,
        seed=seed,
        first_sample=0 if span is None else span.start,
    )
    outputs = tuple(
        replace(o, residual=fit.residual) if o.name == output else o for o in base.outputs
    )
    model = replace(base, outputs=outputs)
    sidecar = sidecar_bytes({output: fit.residual.forest})
    name = sidecar_path(model_path).name
    features = fit.residual.features
    doc = ResidualDoc(
        signal=signal,
        threshold=features.threshold,
        time_constants_s=list(features.time_constants_s),
        file=name,
        sha256=hashlib.sha256(sidecar).hexdigest(),
        trees=trees,
        max_depth=max_depth,
        seed=seed,
        calibration_tf_alone=ResidualFiguresDoc(**vars(fit.tf_alone)),
        calibration_stacked=ResidualFiguresDoc(**vars(fit.stacked)),
    )
    fitted_on = f"fitted on {data.path}" if span is None or span.whole else span.describe("fitted")
    note = (
        f"residual model (Swiss-lathe paper) {fitted_on}: random forest of {trees} trees, "
        f"depth <= {max_depth}, seed {seed}, on {signal} smoothed at "
        f"{list(features.time_constants_s)} s; residue peak-to-peak "
        f"{fit.tf_alone.peak_to_peak_um:.3f} -> {fit.stacked.peak_to_peak_um:.3f} um, RMS "
        f"{fit.tf_alone.rms_um:.3f} -> {fit.stacked.rms_um:.3f} um"
    )
    provenance = parent.provenance
    notes = "; ".join(filter(None, [provenance.notes, note]))
    text = model_to_yaml(
        model,
        description=f"{description}, plus a residual forest on {signal} (Swiss-lathe paper)",
        signals={s: units.get(s) or column_unit(data, s) for s in model.signals()},
        provenance=provenance.model_copy(update={"notes": notes}),
        residuals={output: doc},
        # What the forest does not change stays the parent's: the inputs' consistency checks
        # (the daemon's stand-ins), the probe prior (its sub-models' coefficients are the same;
        # its residue is the TF's alone, so probes are trusted as much as the parent's, not more)
        # and the loop periods the parent ran at without converting.
        consistency=parent.consistency,
        probe_prior=parent.probe_prior,
        run_periods_s=kept_periods(parent.difference_equations),
    )
    return StackedFit(model, fit, text, name, sidecar)
