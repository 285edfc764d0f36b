"""A model judged with probe updates, as the daemon will run it (``compd compare --probe-every``, issue 35 item 7).

The model is run over the record as ``compare`` runs it (its evaluation, a
``--from`` part included); then, in time order, each probe updates the
output's coefficients and bias (:class:`compd.model.probelearner.OutputLearner`,
what the daemon steps: the regressor interpolated at the touch instant, the
bound held over the rows since the last probe taken; it keeps every sample
here, the daemon one a minute). Every sample is predicted with the
parameters as updated at the last probe before it (the file model's output
plus the learner's adjustment, as the daemon adds it); the sample at a
probe instant is predicted before its update. The prediction with probes and the open-loop
one (the model as it is) are judged over the same samples.

Probes come from a file (``--probes``: columns ``time_s`` and the output's
name, values in um on the record's time axis) or are drawn from the measured
column every ``--probe-every`` from the judged part's start (the first one
interval after it) plus seeded Gaussian noise of ``--probe-noise-um``.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from compd.errors import DataFileError
from compd.files.probeprior import OutputPrior, output_prior
from compd.model.metrics import Comparison
from compd.model.probelearner import RECENT_ROWS, OutputLearner, ShiftRefused
from compd.model.proberegressors import RegressorWindow, output_columns
from compd.model.probesettings import DEFAULT_PROBE_INTERVAL_S, ProbeSettings
from compd.model.probeupdate import ProbeStep
from compd.toolkit.evaluate import Evaluation

__all__ = ["RECENT_ROWS", "ProbeRun", "Probes", "read_probes", "run_probes"]

#: After a flagged probe the next comes this soon (s): the daemon's probe-due bit stays set, and
#: a PLC probes at its next tool change (the simulated PLC's ``min_gap_h``: 0.25 h).
REPROBE_AFTER_S = 900.0


@dataclass(frozen=True)
class Probes:
    """Probe instants (s, the record's time axis) and measured values (um), in time order."""

    time_s: np.ndarray
    measured_um: np.ndarray
    #: A probe drawn at any instant (um): a flagged probe is followed by another
    #: :data:`REPROBE_AFTER_S` later, as the daemon's probe-due bit asks the PLC for one.
    #: None (probes read from a file): only the probes given.
    draw: Callable[[float], float] | None = None
    #: The interval they were drawn at (s); None: read from a file.
    every_s: float | None = None

    @property
    def interval_s(self) -> float:
        """How far apart the probes are (s): as drawn, else their median spacing, else the
        daemon's default (one probe)."""
        if self.every_s is not None:
            return self.every_s
        if self.time_s.size >= 2:
            return float(np.median(np.diff(self.time_s)))
        return DEFAULT_PROBE_INTERVAL_S

    @classmethod
    def every(
        cls,
        time_s: np.ndarray,
        measured_um: np.ndarray,
        every_s: float,
        *,
        noise_um: float = 0.5,
        seed: int = 0,
    ) -> Probes:
        """Probes drawn from the measured column every ``every_s`` after its first sample, plus noise."""
        if not every_s > 0:
            raise ValueError(f"the probe interval must be above 0 s, is {every_s}")
        instants = np.arange(time_s[0] + every_s, time_s[-1] + 1e-9, every_s)
        index = np.searchsorted(time_s, instants - 1e-9)
        index = index[index < len(time_s)]
        noise = np.random.default_rng(seed).normal(0.0, noise_um, index.size)
        again = np.random.default_rng([seed, 1])
        t_all, y_all = np.asarray(time_s, dtype=float), np.asarray(measured_um, dtype=float)

        def draw(t_s: float) -> float:
            return float(np.interp(t_s, t_all, y_all) + again.normal(0.0, noise_um))

        return cls(t_all[index], y_all[index] + noise, draw, float(every_s))


@dataclass(frozen=True)
class ProbeRun:
    """One output judged open loop and with probes; ``steps``: every probe as the update took it."""

    output: str
    predicted_um: np.ndarray
    steps: tuple[ProbeStep, ...]
    prior: OutputPrior
    settings: ProbeSettings
    open_loop: Comparison
    with_probes: Comparison

    def count(self, result: str) -> int:
        """Steps with ``result``; a probe flagged then confirmed is counted under both."""
        return sum(step.result == result for step in self.steps)

    @property
    def probe_count(self) -> int:
        return len({step.time_s for step in self.steps})

    def as_dict(self) -> dict[str, Any]:
        """What ``compare --probe-every --json`` prints of this output (and a report embeds)."""
        return {
            "open_loop": self.open_loop.as_dict(),
            "with_probes": self.with_probes.as_dict(),
            "prior": self.prior.prior.source,
            "probes": [
                {
                    "time_s": s.time_s,
                    "measured_um": s.measured_um,
                    "innovation_before_um": s.innovation_before_um,
                    "innovation_after_um": s.innovation_after_um,
                    "result": s.result,
                    "bounded": s.bounded,
                }
                for s in self.steps
            ],
        }


def run_probes(
    evaluation: Evaluation,
    output: str,
    measured: str,
    probes: Probes,
    **settings: float,
) -> ProbeRun:
    """``evaluation``'s ``output`` updated at ``probes``, judged against column ``measured``.

    ``settings`` override :meth:`ProbeSettings.defaults` (``probe_noise_um``,
    ``drift_um_per_sqrt_h``, ``max_departure_um``, ``reject_sigma``).
    """
    owned, names = output_columns(evaluation.compiled, output)
    prior = output_prior(evaluation.model_file, output, names)
    # The daemon's learner, keeping every sample of the record (the daemon keeps one a minute).
    learner = OutputLearner(
        prior.prior,
        ProbeSettings.defaults(prior.prior, interval_s=probes.interval_s, **settings),
        RegressorWindow(row_every_s=0.0, keep_s=math.inf),
    )
    time_s = evaluation.data.time_s
    contributions = evaluation.result.contributions[:, owned]
    x = prior.prior.regressors(contributions)
    open_loop = evaluation.predicted(output)
    fixed = open_loop - contributions.sum(axis=1)  # what no gain scales (a residual model)
    inside = (probes.time_s >= time_s[0]) & (probes.time_s <= time_s[-1])
    if not np.any(inside):
        raise DataFileError(
            evaluation.data.path,
            f"no probe falls in the judged part ({time_s[0]:g} .. {time_s[-1]:g} s)",
            fix="Give probe times on the record's time axis (time_s), inside the judged part",
        )
    predicted = np.empty_like(open_loop)
    steps: list[ProbeStep] = []
    done = 0  # samples predicted so far
    fed = 0  # samples the learner has observed
    queue = deque(zip(probes.time_s[inside], probes.measured_um[inside], strict=True))
    while queue:
        t, z = queue.popleft()
        # Up to and including the probe instant: the parameters before this probe.
        upto = int(np.searchsorted(time_s, t, side="right"))
        predicted[done:upto] = open_loop[done:upto] + learner.adjustments_um(x[done:upto])
        done = upto
        # The ticks up to the touch, and the one after it when it fell between two samples
        # (the daemon has ticked on by the time a probe arrives).
        through = upto if time_s[upto - 1] == t else upto + 1
        if through > fed:
            learner.observe_many(time_s[fed:through], x[fed:through], fixed[fed:through])
            fed = through
        try:
            taken = learner.probe(float(t), float(z))
        except ShiftRefused:  # as the daemon: not applied without a person accepting the shift
            continue
        steps += taken
        # Flagged: still due, so the PLC probes again at its next chance (the daemon's bit).
        again_s = float(t) + REPROBE_AFTER_S
        if (
            probes.draw is not None
            and taken[-1].result == "flagged"
            and again_s <= time_s[-1]
            and (not queue or again_s < queue[0][0])
        ):
            queue.appendleft((again_s, probes.draw(again_s)))
    predicted[done:] = open_loop[done:] + learner.adjustments_um(x[done:])
    y = evaluation.data.column(measured)
    return ProbeRun(
        output,
        predicted,
        tuple(steps),
        prior,
        learner.settings,
        Comparison.of(output, y, open_loop),
        Comparison.of(output, y, predicted),
    )


def read_probes(path: str, output: str, frame_columns: dict[str, Sequence[float]]) -> Probes:
    """Probes from a table's ``time_s`` and ``output`` columns; a missing column names the file and the fix."""
    missing = [c for c in ("time_s", output) if c not in frame_columns]
    if missing:
        raise DataFileError(
            path,
            f"the probe file has no column(s) {missing}",
            fix=f"Give it a time_s column and one named {output!r} (the measured value, um)",
        )
    t = np.asarray(frame_columns["time_s"], dtype=float)
    z = np.asarray(frame_columns[output], dtype=float)
    keep = np.isfinite(t) & np.isfinite(z)
    order = np.argsort(t[keep], kind="stable")
    return Probes(t[keep][order], z[keep][order])
