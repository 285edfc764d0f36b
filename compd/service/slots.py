"""A model slot: one loaded model file, its compiled form, and once started, its runner.

The compensator (:mod:`compd.service.compensator`) holds up to four slots at
once: the active model, the one it blends out of, the one waiting to be
switched in, and the one to restore should the active one fail. A slot also
knows which signals each of its outputs depends on, so that an axis freezes
only for a fault of an input it uses.
"""

from __future__ import annotations

import numpy as np

from compd.files.modelfile import ModelFile
from compd.model.compiled import CompiledModel, ModelState, qualified_names
from compd.model.run import TickRunner


class ModelSlot:
    """A loaded model: its file, compiled form, and once started, its runner."""

    def __init__(self, model_file: ModelFile, compiled: CompiledModel, loaded_at_unix_s: float):
        self.model_file = model_file
        self.compiled = compiled
        self.loaded_at_unix_s = loaded_at_unix_s
        self.runner: TickRunner | None = None
        self.outputs = np.full(len(compiled.output_names), np.nan)
        self.names = list(qualified_names(compiled))
        self._index = {name: i for i, name in enumerate(compiled.output_names)}
        owners = compiled.output_matrix.argmax(axis=0)
        #: Signals each output depends on (inputs, minus signals, gates and positions of its sub-models).
        self.depends: dict[str, set[str]] = {name: set() for name in compiled.output_names}
        for owner, sub in zip(owners, compiled.submodels, strict=True):
            self.depends[compiled.output_names[owner]] |= set(sub.signals())
        for owner, residual in compiled.residuals:  # seed 004's door residual reads its signal too
            self.depends[compiled.output_names[owner]].add(residual.signal)

    @property
    def sha256(self) -> str:
        return self.model_file.sha256

    def start(self, state: ModelState) -> None:
        self.runner = TickRunner(self.compiled, state)

    def output(self, name: str) -> float:
        return float(self.outputs[self._index[name]])
