"""Two sensors at one point: a second reading as the check and the stand-in of a critical one.

A model input may name a partner (``redundant:`` in its signal section), a
second sensor beside it (a second Pt100 at the spindle bearings). The other
sensors of a machine cannot verify its spindle or its air to the fraction of
a degree the offset needs (the spindle's tolerance against its prediction is
degrees, ~8 um/degC); its partner can. Each tick, after both signals passed
their own checks (:mod:`compd.service.loop.signals`) and before the inputs
are checked against each other (:mod:`compd.service.loop.plausibility`):

- one of the pair failed its own checks, the other did not: the other's
  reading is used (the partner's shifted by the pair's usual offset). The
  axes keep compensating on a measurement (this is what a second sensor is
  for), and the status says a sensor needs attention: the primary stands
  ``ESTIMATED`` (level degraded, its status bit; the plausibility check
  judges the partner's reading as the primary's, :meth:`Redundancy.mark`
  marks it after), a partner that failed shows its own health;
- both read: their difference ``d = primary - partner`` less its usual
  value is the excess::

      e = d - b - c * rate

  with ``b`` the pair's usual offset (their class-A offsets) and ``c`` the
  difference of their lags (s): in a transient the slower sensor reads
  behind by its lag times the rate. Both are learnt as the pair reads
  (:mod:`compd.model.pairdifference`: fitted over the first 10 minutes,
  then the lag followed, the offset only while the pair agrees within
  ``k``, so that a drift never becomes the usual). ``|e| > tolerance``
  (widened by the lag's uncertainty times the rate) is a fault
  at once; a slow departure is caught by a two-sided CUSUM (Page 1954)::

      S+ = max(0, S+ + (e - k) Ts),  S- = max(0, S- - (e + k) Ts),  fault if S+ or S- > h

  with allowance ``k = ALLOWANCE * tolerance`` and decision interval
  ``h = DECISION_S * tolerance`` (signal unit x s). A drift of ``r`` (unit/s)
  is flagged after about ``k / r + sqrt(2 h / r)``: for the default 0.5 degC
  tolerance 20 min at 0.5 degC/h (0.17 degC apart), 12 min at 1 degC/h,
  8 min at 2 degC/h (0.26 degC apart);
- during a disagreement the reading used is the one the other sensors
  support: whose change since the departure began (tick ``0``: the last
  tick its CUSUM was 0, Page's change point; readings smoothed over
  :data:`REFERENCE_TAU_S`) is nearer the change of its prediction from the
  other sensors (``plausibility``'s prediction of the primary, ``p``)::

      primary wrong  <=>  |(x1 - x1_0) - (p - p_0)| > |(x2 - x2_0) - (p - p_0)|

  (the prediction's own bias cancels; it may be wrong only where the pair
  differs by less than twice the prediction's drift since ``0``, which
  bounds the error of a wrong choice by twice a stand-in's); that
  difference is averaged over :data:`EVIDENCE_TAU_S` (a transient the
  prediction follows late does not flip the choice), and the choice changes
  once the average favours the other by :data:`HYSTERESIS` x the tolerance. Without a
  prediction the primary is held at the last value the pair agreed on and
  faulted (the axes freeze, as for any faulted input). The status is
  degraded: the sensor set aside has its status bit (the primary: health
  ``ESTIMATED``, its value the partner's; the partner: ``HELD`` at its last
  agreed value);
- the episode ends only after the pair agreed within the allowance ``k`` for
  :data:`CONFIRM_S` seconds in a row (one ERROR line at each end, an event,
  and :attr:`Redundancy.count`).

The pair's usual offset is learnt afresh at each start: a pair that already
disagrees by more than the tolerance when learnt is taken to have none (two
sensors at one point should agree), so the disagreement is flagged.

Pure: the caller passes the time and the prediction, nothing here reads a clock.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import structlog

from compd.faultlog import EventSink, FaultLog
from compd.model.pairdifference import PairDifference
from compd.service.loop.signals import Health, Reading, SignalMonitor

log = structlog.get_logger("compd.service.loop.redundancy")

#: The CUSUM's allowance ``k``, as a fraction of the tolerance: a smaller excess is never summed.
ALLOWANCE = 0.15
#: The CUSUM's decision interval ``h`` over the tolerance (s): the excess summed beyond ``k``.
DECISION_S = 60.0
#: A disagreement ends after the pair agreed within the allowance ``k`` this long (s).
CONFIRM_S = 120.0
#: The evidence of which member the others support is averaged over this long (s)...
EVIDENCE_TAU_S = 600.0
#: ...and the member used changes once the other is nearer by this on average (x tolerance).
HYSTERESIS = 0.2
#: A reference reading is smoothed over this long (s).
REFERENCE_TAU_S = 20.0


@dataclass(frozen=True)
class Pair:
    """A model input (``primary``) and a second sensor of the same point (``partner``).

    ``tolerance``: how far (the signal's ``unit``) their difference may leave its usual value.
    """

    primary: str
    partner: str
    tolerance: float
    unit: str = ""


@dataclass
class _Episode:
    started_s: float
    reason: str
    #: Which member the primary's value comes from: ``primary``, ``partner`` or ``held``.
    using: str = "partner"
    agreeing_s: float = 0.0
    #: How much further the primary moved from what the others say than the partner (averaged).
    evidence: float | None = None


@dataclass(frozen=True)
class _Reference:
    """The pair's readings and the primary's prediction at the last tick they agreed."""

    primary: float
    partner: float
    predicted: float | None


class PairCheck:
    """One pair, tick by tick; :meth:`update` returns the readings of the two to use."""

    def __init__(self, pair: Pair, monitors: Mapping[str, SignalMonitor], period_s: float) -> None:
        self.pair = pair
        self.monitors = monitors
        self.period_s = period_s
        #: The pair's usual difference, lags and rate (:mod:`compd.model.pairdifference`).
        self.difference = PairDifference(period_s, pair.tolerance)
        #: The pair's last difference from its usual, lags taken off (unit; NaN: not yet known).
        self.excess = math.nan
        self.cusum_high = 0.0
        self.cusum_low = 0.0
        self.episode: _Episode | None = None
        #: The pair as it read (smoothed) the last tick each CUSUM was at 0: the estimate of
        #: when a departure upwards / downwards began, the reference a disagreement is judged from.
        self._since_high: _Reference | None = None
        self._since_low: _Reference | None = None
        self._reference: _Reference | None = None
        self._smooth: tuple[float, float] | None = None
        self._agreed = math.nan  # the primary's value the last time the pair agreed
        self._partner_agreed = math.nan
        #: Set aside this tick (the status shows it): "primary", "partner" or None.
        self.set_aside: str | None = None
        self.fault = FaultLog(log, signal=pair.primary, partner=pair.partner, end_level="error")

    @property
    def _k(self) -> float:
        return ALLOWANCE * self.pair.tolerance

    @property
    def usual(self) -> float:
        """The pair's usual difference (primary - partner), 0 until learnt."""
        offset = self.difference.offset
        return 0.0 if offset is None else offset

    def update(
        self, t_s: float, primary: Reading, partner: Reading, predicted: float | None
    ) -> tuple[Reading, Reading]:
        """This tick's readings of the primary and the partner (``predicted``: the primary's
        prediction from the other sensors, None where there is none)."""
        self.set_aside = None
        ok1, ok2 = primary.health is Health.OK, partner.health is Health.OK
        if ok1 and ok2:
            return self._both(t_s, primary, partner, predicted)
        if ok2:  # the primary failed its own checks: its partner stands in
            if self.episode is None:
                self._begin(t_s, f"{self.pair.primary} fails its own checks: {primary.reason}")
                self._reference = self._since_high  # the pair as it last agreed
            assert self.episode is not None
            self.episode.using, self.episode.agreeing_s = "partner", 0.0
            self.set_aside = "primary"
            value = partner.value + self.usual
            why = f"its partner {self.pair.partner} stands in: {primary.reason}"
            return Reading(value, Health.OK, why), partner
        # The partner failed (its own status bit shows it) or both did: the primary as it is,
        # judged by the other sensors alone.
        if self.episode is not None and ok1:
            self._end(
                t_s, primary.value, partner.value, f"{self.pair.partner} fails its own checks"
            )
        return primary, partner

    def _both(
        self, t_s: float, primary: Reading, partner: Reading, predicted: float | None
    ) -> tuple[Reading, Reading]:
        x1, x2, tol, dt = primary.value, partner.value, self.pair.tolerance, self.period_s
        d = x1 - x2
        diff = self.difference
        diff.follow(x1, x2)
        self._follow_readings(x1, x2)
        if diff.offset is None:
            diff.learn(d)
            self._agreed, self._partner_agreed = x1, x2
            self._since_high = self._since_low = self._now(predicted)
            return primary, partner
        self.excess = e = diff.excess(d)
        unsure = diff.lag_uncertainty_s * abs(diff.rate)
        k = self._k + unsure
        self.cusum_high = max(0.0, self.cusum_high + (e - k) * dt)
        self.cusum_low = max(0.0, self.cusum_low - (e + k) * dt)
        alarm = abs(e) > tol + unsure or max(self.cusum_high, self.cusum_low) > DECISION_S * tol
        episode = self.episode
        if episode is None and not alarm:
            diff.learn(d)
            if abs(e) <= k:  # a drift never becomes the usual
                diff.settle(d)
        if episode is None:
            if self.cusum_high == 0.0:
                self._since_high = self._now(predicted)
            if self.cusum_low == 0.0:
                self._since_low = self._now(predicted)
        if episode is None and not alarm:
            self._agreed, self._partner_agreed = x1, x2
            return primary, partner
        if episode is None:
            # Where the departure began: the last tick its CUSUM was at 0 (Page's change point).
            self._reference = self._since_high if e > 0 else self._since_low
            if self._reference is not None:
                self._agreed = self._reference.primary
                self._partner_agreed = self._reference.partner
            how = "at once" if abs(e) > tol else "drifting apart"
            episode = self._begin(
                t_s,
                f"{self.pair.primary} and {self.pair.partner} disagree ({how}): "
                f"{x1:.2f} and {x2:.2f}, {e:+.2f} from their usual {self.usual:+.2f}",
                read=round(x1, 3),
                partner_read=round(x2, 3),
                excess=round(e, 3),
                tolerance=tol,
            )
            episode.using = ""
        agreeing = abs(e) <= k
        if agreeing:
            episode.agreeing_s += dt
            if episode.agreeing_s >= CONFIRM_S:
                self._end(t_s, x1, x2, "the pair agrees again")
                self.cusum_high = self.cusum_low = 0.0
                self._since_high = self._since_low = self._now(predicted)
                self._agreed, self._partner_agreed = x1, x2
                return primary, partner
        else:
            episode.agreeing_s = 0.0
        return self._choose(episode, primary, partner, predicted, agreeing)

    def status(self) -> dict[str, object]:
        """What ``compd status`` shows of the pair: its usual difference, the excess, the episode."""
        episode = self.episode
        return {
            "partner": self.pair.partner,
            "tolerance": self.pair.tolerance,
            "unit": self.pair.unit,
            "usual": None if self.difference.offset is None else round(self.usual, 3),
            "excess": None if math.isnan(self.excess) else round(self.excess, 3),
            "lag_difference_s": round(self.difference.lag_s, 1),
            "fault": None if episode is None else episode.reason,
            "using": None if episode is None else episode.using or None,
        }

    def _follow_readings(self, x1: float, x2: float) -> None:
        """Smooth the two readings over :data:`REFERENCE_TAU_S` (a reference is no single noisy sample)."""
        if self._smooth is None or self.episode is not None:
            self._smooth = (x1, x2)
            return
        a = math.exp(-self.period_s / REFERENCE_TAU_S)
        s1, s2 = self._smooth
        self._smooth = (a * s1 + (1 - a) * x1, a * s2 + (1 - a) * x2)

    def _now(self, predicted: float | None) -> _Reference:
        assert self._smooth is not None
        return _Reference(*self._smooth, predicted)

    def _choose(
        self,
        episode: _Episode,
        primary: Reading,
        partner: Reading,
        predicted: float | None,
        agreeing: bool,
    ) -> tuple[Reading, Reading]:
        """The readings in a disagreement: the member the other sensors support is used."""
        x1, x2, tol = primary.value, partner.value, self.pair.tolerance
        ref = self._reference
        if predicted is None or ref is None or ref.predicted is None:
            episode.using = "held"
            self.set_aside = "primary"
            why = f"no prediction to judge the pair by: {episode.reason}"
            held = Reading(self._agreed, Health.FAULTED, why)
            self.monitors[self.pair.primary].rebase(held, x1)
            return held, partner
        moved = predicted - ref.predicted
        # > 0: the primary moved away from what the others say more than the partner did.
        gap = abs(x1 - ref.primary - moved) - abs(x2 - ref.partner - moved)
        if episode.evidence is None:
            episode.evidence = gap
        else:  # a transient the prediction follows late does not flip the choice
            a = math.exp(-self.period_s / EVIDENCE_TAU_S)
            episode.evidence = a * episode.evidence + (1 - a) * gap
        evidence = episode.evidence
        if episode.using not in ("primary", "partner"):
            episode.using = "partner" if evidence > 0 else "primary"
        elif episode.using == "partner" and evidence < -HYSTERESIS * tol:
            episode.using = "primary"
        elif episode.using == "primary" and evidence > HYSTERESIS * tol:
            episode.using = "partner"
        if agreeing:  # agreeing again, not yet long enough: nothing set aside
            return primary, partner
        if episode.using == "primary":
            self.set_aside = "partner"
            why = f"set aside, {self.pair.primary} used (the other sensors support it): {episode.reason}"
            return primary, Reading(self._partner_agreed, Health.HELD, why)
        self.set_aside = "primary"
        why = f"{self.pair.partner} used (the other sensors support it): {episode.reason}"
        return Reading(x2 + self.usual, Health.OK, why), partner

    def _begin(self, t_s: float, reason: str, **details: object) -> _Episode:
        self.episode = _Episode(t_s, reason)
        self.fault.failed("redundant pair: " + reason, unit=self.pair.unit, **details)
        return self.episode

    def _end(self, t_s: float, x1: float, x2: float, why: str) -> None:
        episode = self.episode
        assert episode is not None
        self.episode = None
        self.fault.cleared(
            f"redundant pair: {why}: {self.pair.primary} used again",
            read=round(x1, 3),
            partner_read=round(x2, 3) if math.isfinite(x2) else str(x2),
            lasted_s=round(t_s - episode.started_s, 1),
        )


class Redundancy:
    """Every pair of a config; :meth:`apply` before the plausibility check, :meth:`mark` after."""

    def __init__(
        self, pairs: list[Pair], monitors: Mapping[str, SignalMonitor], period_s: float
    ) -> None:
        self.checks = [PairCheck(p, monitors, period_s) for p in pairs]

    @property
    def count(self) -> int:
        """Episodes begun since start (a pair disagreed, or one of it failed its own checks)."""
        return sum(c.fault.episodes for c in self.checks)

    def report_to(self, sink: EventSink) -> None:
        for check in self.checks:
            check.fault.sink = sink

    def vouched(self) -> set[str]:
        """The primaries whose two sensors read and agree this tick: what the other sensors say
        against them is their prediction's error, not theirs (:mod:`compd.service.loop.plausibility`)."""
        return {c.pair.primary for c in self.checks if c.episode is None and c.set_aside is None}

    def apply(
        self, t_s: float, readings: Mapping[str, Reading], predicted: Mapping[str, float | None]
    ) -> dict[str, Reading]:
        """The readings with each pair's primary as its pair says (``predicted``: each primary's
        prediction from the other sensors, where there is one)."""
        out = dict(readings)
        for check in self.checks:
            p = check.pair
            out[p.primary], out[p.partner] = check.update(
                t_s, readings[p.primary], readings[p.partner], predicted.get(p.primary)
            )
        return out

    def mark(self, readings: Mapping[str, Reading]) -> dict[str, Reading]:
        """After the plausibility check: a primary set aside for its partner shows as ``ESTIMATED``.

        Its value went to the plausibility check as an OK reading (it is a
        measurement of the point, judged as one); where that check left it
        OK, its health now says a stand-in is used, for the status.
        """
        out = dict(readings)
        for check in self.checks:
            name = check.pair.primary
            reading = out[name]
            if check.set_aside == "primary" and reading.health is Health.OK:
                out[name] = Reading(reading.value, Health.ESTIMATED, reading.reason)
        return out
