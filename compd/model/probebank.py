"""Probe updates that differ in how far the calibration's model may move, weighted by the probes (issue 42).

The calibration's posterior says how well the data pinned each direction of
the model's coefficients, not how far a new programme or a changed machine
will depart from the calibration where the data could not decide. So two
updates (:class:`~compd.model.probeupdate.ProbeUpdater`) run side by side on
the same probes (:data:`MEMBERS`), in the model's coefficients:

- ``gains``: each sub-model's coefficient moves in proportion to itself, as
  the calibration's posterior of gains on the sub-models says (the update
  before issue 42, which the random machines favour), and the bias;
- ``narrow``: the coefficients at a hundredth of the prior's variance in the
  model's coefficients, and the bias: a term the calibration shrank to almost
  nothing may grow, and inputs that move together may trade weight (what the
  shared real record needs: 80.5 / 81.7 % at 2 h where ``gains`` alone did
  73.8 / 75.2).

``gains`` counts the calibration residue's transient variance over the probe
interval as probe noise (:data:`COUNTS_TRANSIENT`): what came and went
within an interval during the calibration (a door, a chiller's cycle) is in
a probe's innovation and gone before the next probe.

Each probe weighs them by how likely its innovation was under each (their
predictive likelihood ``N(e_k; 0, S_k)``: multiple-model adaptive
estimation, Magill 1965): the trust in each follows how well it predicted
the probes; the output is their weighted mean. No weight falls below
:data:`WEIGHT_FLOOR`, so a later change of the machine can move it back.

The bank is a :class:`ProbeUpdater` to its users: ``theta`` and
``covariance`` are the mixture's (mean, and covariance with the spread of
the members), the flagging and confirming rules judge the mixture's
prediction, and each probe taken is taken by every member. numpy only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from compd.model.probesettings import ProbeSettings
from compd.model.probeupdate import ProbeResult, ProbeStep, ProbeUpdater
from compd.model.updateprior import Prior

__all__ = ["COUNTS_TRANSIENT", "MEMBERS", "WEIGHT_FLOOR", "UpdaterBank", "member_prior"]

#: The members: a name and the share of the prior's variance their sub-models' block keeps (or
#: ``"gains"``). Chosen on the random machines (seeds 0-99) and the shared record, checked on
#: seeds 1000-1099 (benchmarks/bench_probes.py; benchmarks/README, "Probe updates judged
#: offline"): the calibration's own coefficient prior as a member (share 1), shares 0.03 and
#: 0.1, a member that learns nothing, and Sage-Husa noise estimation each lost more machines
#: than they won.
MEMBERS: tuple[tuple[str, float | str], ...] = (
    ("gains", "gains"),
    ("narrow", 0.01),
)
#: The members that count the calibration residue's transient variance as probe noise
#: (:attr:`~compd.model.probesettings.ProbeSettings.transient_variance_um2`). Chosen on the
#: random machines (seeds 0-99) and checked on seeds 1000-1099 and the shared record
#: (benchmarks/README, "The transient variance"): both members gained more on the random
#: machines but cost the shared record 2.5 points at 2 h (80.5 -> 78.0 %); ``gains`` alone
#: kept the record and still gained on every figure of both seed sets.
COUNTS_TRANSIENT = frozenset({"gains"})
#: No member's weight falls below this.
WEIGHT_FLOOR = 1e-3


def member_prior(prior: Prior, share: float | str) -> Prior:
    """``prior`` as a member starts from it: ``share`` of the sub-models' block of its covariance,
    or (``"gains"``) the gains' posterior (:attr:`Prior.gains_covariance`)."""
    if isinstance(share, str):
        gains = prior.gains_covariance
        return prior if gains is None else replace(prior, covariance=gains.copy())
    scale = np.full(len(prior.names), math.sqrt(share))
    scale[-1] = 1.0
    return replace(prior, covariance=prior.covariance * np.outer(scale, scale))


@dataclass
class UpdaterBank(ProbeUpdater):
    """The members of :data:`MEMBERS` and their weights, seen as one update (the module docstring)."""

    members: list[ProbeUpdater] = field(init=False)
    weights: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        super().__post_init__()
        self.members = [
            ProbeUpdater(member_prior(self.prior, share), self.settings) for _, share in MEMBERS
        ]
        self.weights = np.full(len(MEMBERS), 1.0 / len(MEMBERS))
        self.mix()

    def _member_settings(self, k: int) -> ProbeSettings:
        """The bank's settings as member ``k`` takes them: with the transient variance as probe
        noise where :data:`COUNTS_TRANSIENT` says so."""
        settings = self.settings
        if MEMBERS[k][0] not in COUNTS_TRANSIENT or settings.transient_variance_um2 <= 0.0:
            return settings
        noise = math.hypot(settings.probe_noise_um, math.sqrt(settings.transient_variance_um2))
        return replace(settings, probe_noise_um=noise)

    def mix(self) -> None:
        """``theta``: the members' weighted mean (:attr:`covariance` is mixed when asked for)."""
        self.theta = self.weights @ np.array([m.theta for m in self.members])

    @property
    def covariance(self) -> np.ndarray:
        """The mixture's covariance ``sum_k w_k (P_k + d_k d_k')``, ``d_k`` a member's departure
        from the mean (a new array; only a saved state and an export ask for it)."""
        spread = np.array([m.theta for m in self.members]) - self.theta
        covariance: np.ndarray = spread.T @ (self.weights[:, None] * spread)
        for wk, member in zip(self.weights, self.members, strict=True):
            covariance += wk * member.covariance
        mixture: np.ndarray = 0.5 * (covariance + covariance.T)
        return mixture

    @covariance.setter
    def covariance(self, value: np.ndarray) -> None:
        """The members carry the covariance; the bank keeps none of its own."""

    def parameter_variance(self, x: np.ndarray) -> float:
        """``x' P x`` of the mixture without forming it: each member's, plus the members' spread."""
        return sum(
            float(wk) * (member.parameter_variance(x) + float(x @ (member.theta - self.theta)) ** 2)
            for wk, member in zip(self.weights, self.members, strict=True)
        )

    def snapshot(self) -> tuple[Any, ...]:
        """What a probe changes, copied: :meth:`put_back` returns the bank to it."""
        return (
            [m.snapshot() for m in self.members],
            self.weights.copy(),
            self.theta.copy(),
            self.last_time_s,
            self.drifted_to_s,
            self.pending,
        )

    def put_back(self, snapshot: tuple[Any, ...]) -> None:
        members, self.weights, self.theta, *times = snapshot
        self.last_time_s, self.drifted_to_s, self.pending = times
        for member, saved in zip(self.members, members, strict=True):
            member.put_back(saved)

    def finite(self) -> bool:
        return bool(np.all(np.isfinite(self.weights))) and all(m.finite() for m in self.members)

    def _widen_bias(self, variance_um2: float) -> None:
        for member in self.members:
            member._widen_bias(variance_um2)

    def _take(
        self,
        time_s: float,
        x: np.ndarray,
        fixed_um: float,
        measured_um: float,
        predicted_um: float,
        sd_um: float,
        result: ProbeResult,
    ) -> ProbeStep:
        """Every member takes the probe; the weights follow each one's predictive likelihood."""
        log_likelihood = np.empty(len(self.members))
        bounded = False
        for k, member in enumerate(self.members):
            member.settings = self._member_settings(k)
            predicted = float(fixed_um + x @ member.theta)
            sd = member.predicted_sd_um(x, time_s)
            z = (measured_um - predicted) / sd
            log_likelihood[k] = -math.log(sd) - 0.5 * z * z
            member._recent = self._recent
            step = member._take(time_s, x, fixed_um, measured_um, predicted, sd, result)
            bounded = bounded or step.bounded
        weights = self.weights * np.exp(log_likelihood - log_likelihood.max())
        weights = np.maximum(weights / weights.sum(), WEIGHT_FLOOR)
        self.weights = weights / weights.sum()
        self.drifted_to_s = time_s
        self.mix()
        after = measured_um - float(fixed_um + x @ self.theta)
        innovation = measured_um - predicted_um
        return ProbeStep(
            time_s, measured_um, predicted_um, sd_um, innovation, after, result, bounded
        )
