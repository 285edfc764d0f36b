"""Initial-state estimation: start a model where the measurement says the machine was.

A record that starts mid-transient (a file split off a longer log, a machine
still cooling from the last shift) is judged unfairly from a steady start:
the model knows nothing of the heat already in the structure, so its slow
sub-models begin at equilibrium while the machine does not. MATLAB's
``compare`` estimates the initial state; so does this, on a window at the
record's start::

    measured(k) - y_steady(k) = sum_{s,j} F_sj(k) dz_sj,   k < window

where ``F_sj`` is the free response of sub-model ``s``'s output to a unit
change of its ``j``-th state (gain, gates and position factors applied: the
response is linear in the state), solved by ridge-regularised least squares
(identical responses, such as a lag bank's lags of one time constant, share
their correction). Residual-forest states are left as they are.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from compd.errors import ModelError
from compd.model.compiled import CompiledModel, ModelState
from compd.model.run import simulate

#: Ridge weight relative to the mean diagonal of ``F^T F``: enough to pick the smallest
#: correction among responses a short window cannot tell apart, too little to bias it.
RIDGE_RELATIVE = 1e-6


def estimate_initial_state(
    compiled: CompiledModel,
    signals: np.ndarray,
    measured: Mapping[str, np.ndarray],
    start: ModelState,
    window: int,
) -> ModelState:
    """The state that best explains ``measured`` (output name -> um) over the first ``window`` samples.

    ``signals`` is the record in ``compiled.signals`` order; ``start`` the
    state the correction is added to (e.g. the steady state at the first sample).
    """
    if not measured:
        raise ModelError("initial-state estimation needs at least one measured output")
    window = int(min(window, signals.shape[0]))
    if window < 2:
        raise ModelError("initial-state estimation needs a window of at least 2 samples")
    head = np.asarray(signals[:window], dtype=float)
    base = simulate(compiled, head, start)
    rows = [compiled.output_names.index(name) for name in measured]
    residue = np.concatenate(
        [
            np.asarray(measured[name], dtype=float)[:window] - base.outputs[:, o]
            for name, o in zip(measured, rows, strict=True)
        ]
    )
    columns: list[np.ndarray] = []
    places: list[tuple[int, int]] = []
    for j in range(start.z.shape[1]):
        # Every sub-model's state j at once: each contribution depends on its own state only.
        z = start.z.copy()
        z[:, j] += 1.0
        moved = simulate(compiled, head, ModelState(z, start.reference, start.residual))
        delta = moved.contributions - base.contributions  # (window, n_submodels)
        for s in range(compiled.n_submodels):
            column = np.concatenate([compiled.output_matrix[o, s] * delta[:, s] for o in rows])
            if np.any(column):
                columns.append(column)
                places.append((s, j))
    if not columns:
        return start
    f = np.column_stack(columns)
    gram = f.T @ f
    weight = RIDGE_RELATIVE * float(np.mean(np.diag(gram)))
    correction = np.linalg.solve(gram + weight * np.eye(gram.shape[0]), f.T @ residue)
    z = start.z.copy()
    for (s, j), dz in zip(places, correction, strict=True):
        z[s, j] += dz
    if not np.all(np.isfinite(z)):
        raise ModelError("the estimated initial state is not finite")
    return ModelState(z, start.reference, start.residual)
