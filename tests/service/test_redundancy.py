"""A model input and its second sensor: which reading is used, when the pair is a fault, when it ends."""

from __future__ import annotations

import math

import numpy as np
import pytest

from compd.model.pairdifference import BASELINE_S
from compd.service.loop.redundancy import (
    CONFIRM_S,
    Pair,
    PairCheck,
    Redundancy,
)
from compd.service.loop.signals import Checks, Health, Reading, SignalMonitor

PAIR = Pair("T_spindle_degC", "T_spindle_b_degC", 0.5, "degC")
NOISE_DEGC = 0.015


def monitors() -> dict[str, SignalMonitor]:
    return {name: SignalMonitor(name, Checks()) for name in (PAIR.primary, PAIR.partner)}


class Bench:
    """One pair fed tick by tick: the true temperature, each sensor's error, the prediction."""

    def __init__(self, seed: int = 0, usual_degc: float = 0.2) -> None:
        self.check = PairCheck(PAIR, monitors(), 1.0)
        self.rng = np.random.default_rng(seed)
        self.usual = usual_degc  # primary - partner, fault-free
        self.t = 0

    def step(
        self,
        true: float,
        *,
        primary_error: float = 0.0,
        partner_error: float = 0.0,
        predicted: float | str | None = "true",
        primary_health: Health = Health.OK,
    ) -> tuple[Reading, Reading]:
        e1, e2 = self.rng.normal(0.0, NOISE_DEGC, 2)
        x1 = true + self.usual + primary_error + e1
        x2 = true + partner_error + e2
        p = true + 0.7 if predicted == "true" else predicted  # a prediction with its own bias
        assert p is None or isinstance(p, float)
        reading = Reading(x1, primary_health, "" if primary_health is Health.OK else "stuck")
        out = self.check.update(float(self.t), reading, Reading(x2, Health.OK), p)
        self.t += 1
        return out

    def run(self, seconds: int, temperature=lambda t: 30.0, **kw) -> list[tuple[Reading, Reading]]:
        return [self.step(temperature(self.t), **kw) for _ in range(seconds)]


def learnt(seed: int = 0) -> Bench:
    bench = Bench(seed)
    bench.run(int(BASELINE_S) + 60)
    return bench


def test_agreeing_pair_passes_the_primary_through_and_learns_the_usual_difference():
    """While the pair agrees, the primary's reading is used unchanged and their usual difference is learnt."""
    bench = Bench()
    out = bench.run(int(BASELINE_S) + 600)
    assert all(p.health is Health.OK and q.health is Health.OK for p, q in out)
    assert bench.check.usual == pytest.approx(0.2, abs=0.01)
    assert bench.check.episode is None and bench.check.fault.episodes == 0


def test_an_offset_on_the_primary_is_caught_at_once_and_its_partner_used():
    """A primary 8 degC off: flagged the same tick, the partner's reading (plus the usual) used, status degraded."""
    bench = learnt()
    primary, _ = bench.step(30.0, primary_error=8.0)
    assert bench.check.episode is not None and bench.check.fault.episodes == 1
    assert primary.value == pytest.approx(30.2, abs=0.08)
    assert bench.check.set_aside == "primary"
    marked = Redundancy([PAIR], monitors(), 1.0)
    marked.checks[0] = bench.check
    assert marked.mark({PAIR.primary: primary})[PAIR.primary].health is Health.ESTIMATED


def test_an_offset_on_the_partner_sets_the_partner_aside():
    """A partner 8 degC off: the primary is used as read, the partner held at its last agreed value."""
    bench = learnt()
    before = bench.step(30.0)[1].value
    primary, partner = bench.step(30.0, partner_error=8.0)
    assert primary.health is Health.OK and primary.value == pytest.approx(30.2, abs=0.08)
    assert partner.health is Health.HELD and partner.value == pytest.approx(before, abs=0.05)
    assert bench.check.set_aside == "partner"


@pytest.mark.parametrize(("rate_degc_per_h", "within_s"), [(0.5, 25 * 60), (2.0, 10 * 60)])
def test_a_slow_drift_is_caught_by_the_pair_within_minutes(rate_degc_per_h, within_s):
    """A primary drifting 0.5 degC/h is flagged within 25 min, 2 degC/h within 10 min, before 0.3 degC."""
    bench = learnt()
    rate = rate_degc_per_h / 3600
    for s in range(within_s):
        primary, _ = bench.step(30.0, primary_error=rate * s)
        if bench.check.episode is not None:
            break
    assert bench.check.episode is not None, "not caught"
    assert rate * s < 0.3
    primary, _ = bench.step(30.0, primary_error=rate * s)
    assert primary.value == pytest.approx(30.2, abs=0.08), "the partner is used"


def test_a_transient_read_with_different_lags_is_no_fault():
    """Two sensors of 20 and 50 s lag through warm-ups and cool-downs of 0.02 degC/s never disagree."""
    check = PairCheck(PAIR, monitors(), 1.0)
    rng = np.random.default_rng(1)
    a1, a2 = math.exp(-1 / 20), math.exp(-1 / 50)
    y1 = y2 = 25.0
    for t in range(8 * 3600):
        phase = (t // 1200) % 3  # 20 min warming, 20 min cooling, 20 min steady
        true = 25.0 + 0.02 * min(t % 1200, 600) * (1 if phase == 0 else 0)
        true = true if phase != 1 else 37.0 - 0.02 * min(t % 1200, 600)
        y1 = a1 * y1 + (1 - a1) * true
        y2 = a2 * y2 + (1 - a2) * true
        x1, x2 = y1 + 0.1 + rng.normal(0, NOISE_DEGC), y2 + rng.normal(0, NOISE_DEGC)
        check.update(float(t), Reading(x1, Health.OK), Reading(x2, Health.OK), true)
    assert check.fault.episodes == 0
    assert check.difference.lag_s > 0  # the primary is the faster


def test_a_primary_failing_its_own_checks_is_replaced_by_its_partner():
    """A primary that fails its own checks: the partner's reading is used and judged, set aside, one episode."""
    bench = learnt()
    outs = bench.run(100, primary_health=Health.HELD)
    assert all(p.health is Health.OK for p, _ in outs)  # the plausibility check judges it
    assert bench.check.set_aside == "primary"
    assert outs[-1][0].value == pytest.approx(30.2, abs=0.08)
    assert "stands in" in outs[-1][0].reason
    assert bench.check.fault.episodes == 1


def test_the_episode_ends_only_after_the_pair_agreed_for_a_while():
    """After the fault the partner is still used for CONFIRM_S seconds of agreement, then the primary again."""
    bench = learnt()
    bench.run(300, primary_error=8.0)
    back = bench.run(int(CONFIRM_S) - 5)
    assert bench.check.episode is not None
    assert all(p.health is Health.OK for p, _ in back)  # agreeing: nothing set aside
    bench.run(10)
    assert bench.check.episode is None and bench.check.fault.episodes == 1


def test_without_a_prediction_the_primary_is_held_and_faulted():
    """A disagreement nobody can judge: the primary held at the last agreed value and faulted."""
    bench = learnt()
    last = bench.step(30.0)[0].value
    primary, _ = bench.step(30.0, primary_error=8.0, predicted=None)
    assert primary.health is Health.FAULTED and primary.value == pytest.approx(last, abs=0.05)


def test_the_other_sensors_pick_the_member_that_moved_with_them():
    """In a disagreement the member whose change follows the prediction's is used, whichever it is."""
    for wrong in ("primary", "partner"):
        bench = learnt()
        warm = lambda t: 30.0 + 0.002 * (t - BASELINE_S - 60)  # noqa: E731
        errors = {f"{wrong}_error": -3.0}
        outs = bench.run(300, temperature=warm, **errors)
        primary, _ = outs[-1]
        true = warm(bench.t - 1)
        assert primary.value == pytest.approx(true + 0.2, abs=0.1), wrong
        assert bench.check.set_aside == wrong


def test_a_pair_apart_from_the_start_is_a_fault_once_learnt():
    """A pair 5 degC apart from the start learns no usual difference: it is a fault once learnt."""
    bench = Bench(usual_degc=5.0)
    bench.run(int(BASELINE_S) + 5)
    assert bench.check.usual == 0.0 and bench.check.episode is not None
