"""A model file's named gains: which sub-models each scales, and a run split per gain.

Post-process 2024 eq. 6 scales whole sub-models by gains ``g1, g2, ...``; the model
file names them (``gain_name`` per sub-model, shared names share a value).
Here the names are resolved against a model (plus any sub-model a user frees
with ``--bounds NAME=LOW:HIGH``), and a model run over a data file is split
into each gain's contribution at gain 1 and the fixed rest (the other
sub-models, residual forests, biases), so that any gain vector's output is
``fixed + C @ g`` without running the model again (see :mod:`compd.model.gains`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from compd.errors import ModelFileError
from compd.files.data import DataSet
from compd.files.modelfile import ModelFile
from compd.model.structure import Model
from compd.toolkit.evaluate import InitialState, evaluate


def parse_bounds(text: str | None, where_path: str) -> dict[str, tuple[float, float]]:
    """``g1=0:2,g2=0.5:1.1`` -> ``{"g1": (0, 2), "g2": (0.5, 1.1)}``."""
    bounds: dict[str, tuple[float, float]] = {}
    for item in (text or "").split(","):
        if not item.strip():
            continue
        key, _, interval = item.partition("=")
        low_text, _, high_text = interval.partition(":")
        try:
            low, high = float(low_text), float(high_text)
        except ValueError:
            low = high = math.nan
        key = key.strip()
        if not key or not (math.isfinite(low) and math.isfinite(high) and low < high):
            raise ModelFileError(
                where_path,
                f"cannot read the bound {item.strip()!r}",
                where="--bounds",
                fix="Write NAME=LOW:HIGH with LOW < HIGH, comma-separated, e.g. g1=0:2,g2=0.5:1.1",
            )
        bounds[key] = (low, high)
    return bounds


@dataclass(frozen=True)
class Gain:
    """One optimised gain: its key and the sub-models (output index, sub-model index) it scales."""

    key: str
    members: tuple[tuple[int, int], ...]
    value: float


def model_gains(
    model_file: ModelFile, bounds: dict[str, tuple[float, float]], outputs: list[str]
) -> list[Gain]:
    """The gains to optimise: every ``gain_name`` in ``outputs``, plus sub-models named in ``bounds``."""
    model = model_file.model
    members: dict[str, list[tuple[int, int]]] = {}
    unnamed: dict[str, list[tuple[int, int]]] = {}
    for o, output in enumerate(model.outputs):
        for s, sub in enumerate(output.submodels):
            if sub.gain_name is not None:
                members.setdefault(sub.gain_name, []).append((o, s))
            elif output.name in outputs:
                unnamed.setdefault(sub.name, []).append((o, s))
    scoped = {k for k, v in members.items() if any(model.outputs[o].name in outputs for o, _ in v)}
    chosen = {k: members[k] for k in sorted(scoped)}
    for key in bounds:
        if key in members:
            chosen[key] = members[key]
        elif key in unnamed:
            chosen[key] = unnamed[key]
        else:
            raise ModelFileError(
                model_file.path,
                f"--bounds names {key!r}, which is neither a gain_name nor a sub-model without one "
                f"in output(s) {', '.join(outputs)}",
                where="--bounds",
                fix=f"Use a gain name ({', '.join(sorted(members)) or 'none in this file'}) or a "
                f"sub-model name ({', '.join(sorted(unnamed)) or 'none'})",
            )
    if not chosen:
        raise ModelFileError(
            model_file.path,
            "the model names no gain to update",
            where=f"outputs {', '.join(outputs)}",
            fix="Add 'gain_name: g1' to the sub-models to scale (Post-process 2024 eq. 6), or pass "
            "--bounds SUBMODEL=LOW:HIGH",
        )
    gains = []
    for key, places in chosen.items():
        values = {model.outputs[o].submodels[s].gain for o, s in places}
        if len(values) > 1:
            raise ModelFileError(
                model_file.path,
                f"the sub-models sharing gain {key!r} have different gains {sorted(values)}",
                where=f"gain_name {key}",
                fix="Give them one gain value, or different gain names",
            )
        gains.append(Gain(key, tuple(places), values.pop()))
    return gains


def with_gains(model: Model, gains: list[Gain], values: np.ndarray) -> Model:
    """``model`` with each gain's sub-models set to its value; all else (its ambient zero,
    residual forests, biases) as it was."""
    new = {place: float(v) for gain, v in zip(gains, values, strict=True) for place in gain.members}
    outputs = tuple(
        dataclasses.replace(
            output,
            submodels=tuple(
                dataclasses.replace(sub, gain=new.get((o, s), sub.gain))
                for s, sub in enumerate(output.submodels)
            ),
        )
        for o, output in enumerate(model.outputs)
    )
    return dataclasses.replace(model, outputs=outputs)


@dataclass(frozen=True, eq=False)
class Decomposition:
    """Per output: each gain's contribution at gain 1 ``(N, G)`` and the fixed rest ``(N,)``, um."""

    data: DataSet
    contributions: dict[str, np.ndarray]
    fixed: dict[str, np.ndarray]

    def predicted(self, output: str, gains: np.ndarray) -> np.ndarray:
        values: np.ndarray = self.fixed[output] + self.contributions[output] @ gains
        return values


def decompose(
    model_file: ModelFile, gains: list[Gain], data: DataSet, *, init: InitialState = "steady"
) -> Decomposition:
    """Run the model once over ``data`` with the optimised gains at 1 and split its outputs."""
    unit = with_gains(model_file.model, gains, np.ones(len(gains)))
    evaluation = evaluate(
        ModelFile(model_file.path, model_file.sha256, unit, model_file.doc), data, init=init
    )
    per_sub = evaluation.result.contributions
    column = {}
    flat = 0
    for o, output in enumerate(unit.outputs):
        for s in range(len(output.submodels)):
            column[(o, s)] = flat
            flat += 1
    contributions, fixed = {}, {}
    for o, output in enumerate(unit.outputs):
        gained = np.zeros((len(data), len(gains)))
        free: set[int] = set()
        for j, gain in enumerate(gains):
            cols = [column[p] for p in gain.members if p[0] == o]
            free.update(cols)
            if cols:
                gained[:, j] = per_sub[:, cols].sum(axis=1)
        contributions[output.name] = gained
        # The rest is the output less what the gains scale: the other sub-models, and its
        # residual forest and bias, which the written model keeps and adds too.
        fixed[output.name] = evaluation.predicted(output.name) - gained.sum(axis=1)
    return Decomposition(data, contributions, fixed)
