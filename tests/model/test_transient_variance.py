"""The calibration residue's transient variance: what a probe sees that is gone before the next one."""

from __future__ import annotations

import math

import numpy as np
import pytest

from compd.errors import ModelError
from compd.model.probebank import UpdaterBank
from compd.model.probesettings import ProbeSettings
from compd.model.updateprior import BIAS, Prior, transient_variances


def _residue(hours: float = 48.0, seed: int = 0) -> tuple[np.ndarray, float]:
    """A slow error (a day's period, 1 um^2) plus a transient one (a door's 10 min
    episodes, about 4 um^2), sampled every 30 s."""
    rng = np.random.default_rng(seed)
    dt_s = 30.0
    t = np.arange(0.0, hours * 3600.0, dt_s)
    slow = math.sqrt(2.0) * np.sin(2 * np.pi * t / 86400.0)
    door = np.repeat(rng.choice([-2.0, 2.0], size=t.size // 20 + 1), 20)[: t.size]
    return slow + door, dt_s


def test_the_transient_variance_is_the_part_gone_within_the_interval() -> None:
    """At 2 h the door's 4 um^2 and little of the day's slow 1 um^2; at 15 min less of the door."""
    residue, dt_s = _residue()
    pairs = dict(transient_variances(residue, dt_s))
    assert pairs[7200.0] == pytest.approx(4.0, rel=0.15)
    assert pairs[900.0] < pairs[7200.0]
    assert pairs[28800.0] > pairs[7200.0]  # over 8 h part of the day's swing is gone too
    assert 86400.0 not in pairs  # no interval as long as the record's half


def test_a_prior_interpolates_its_transient_variance_and_knows_none_without_it() -> None:
    """Between the stored intervals linearly, from 0 at 0 s, the last value beyond; 0 unknown."""
    prior = Prior(("a", BIAS), np.eye(2), 1.0, transient_um2=((3600.0, 1.0), (7200.0, 3.0)))
    assert prior.transient_variance_um2(1800.0) == pytest.approx(0.5)
    assert prior.transient_variance_um2(5400.0) == pytest.approx(2.0)
    assert prior.transient_variance_um2(86400.0) == pytest.approx(3.0)
    assert Prior(("a", BIAS), np.eye(2), 1.0).transient_variance_um2(7200.0) == 0.0
    with pytest.raises(ModelError, match="transient"):
        Prior(("a", BIAS), np.eye(2), 1.0, transient_um2=((7200.0, -1.0),))


def test_a_model_better_than_its_probes_is_not_pushed_around_by_transient_errors() -> None:
    """Innovations of +-4 um that alternate probe to probe (a door open at one, shut at the next),
    on a calibration whose residue showed such a transient: the bank's prediction moves far less
    than with the probe noise alone, and the error it adds between probes is smaller."""
    prior = Prior(
        ("spindle", BIAS),
        np.diag([0.09, 4.0]),
        2.0,
        output_peak_um=40.0,
        transient_um2=((3600.0, 14.0), (7200.0, 16.0)),
    )
    x = np.array([1.0, 1.0])

    def largest_move(settings: ProbeSettings) -> float:
        bank = UpdaterBank(prior, settings)
        moves = []
        for k in range(8):
            bank.probe(7200.0 * (k + 1), x, 1.0 + (4.0 if k % 2 else -4.0))
            moves.append(abs(float(x @ (bank.theta - prior.mean))))
        return max(moves)

    plain = ProbeSettings.defaults(prior, transient_variance_um2=0.0)
    with_transient = ProbeSettings.defaults(prior, interval_s=7200.0)
    assert with_transient.transient_variance_um2 == pytest.approx(16.0)
    assert largest_move(with_transient) < 0.7 * largest_move(plain)
