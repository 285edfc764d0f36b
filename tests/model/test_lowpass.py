"""Matched causal low-passes: the filter equation, the TF product and the least-squares match."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.signal
from numpy.testing import assert_allclose

from compd.errors import ModelError
from compd.model.lowpass import LowPass, cascade, match_lowpass
from compd.model.transfer import DiscreteTF

TS = 10.0


def test_one_stage_is_the_sensor_lag_equation():
    """One stage computes y[k] = a y[k-1] + (1 - a) x[k] with a = exp(-Ts/tau), from equilibrium with x[0]."""
    rng = np.random.default_rng(1)
    x = 20.0 + rng.standard_normal(200)
    a = np.exp(-TS / 300.0)
    expected = np.empty_like(x)
    previous = x[0]
    for k, value in enumerate(x):
        previous = a * previous + (1.0 - a) * value
        expected[k] = previous
    assert_allclose(LowPass(300.0).apply(x, TS), expected, rtol=0, atol=1e-12)


@pytest.mark.parametrize("stages", [1, 2])
def test_low_pass_has_unity_static_gain(stages):
    """A low-pass of either order passes a constant unchanged (B(1)/A(1) = 1)."""
    assert LowPass(120.0, stages).tf(TS).static_gain() == pytest.approx(1.0, abs=1e-12)


@pytest.mark.parametrize("stages", [1, 2])
def test_baked_product_equals_filtering_then_the_tf(stages):
    """TF x LP applied to the raw input equals the TF applied to the low-passed input, from rest."""
    rng = np.random.default_rng(2)
    u = np.cumsum(rng.standard_normal(3000)) * 0.01 + 0.4 * np.sin(np.arange(3000) / 14.0)
    tf = DiscreteTF.from_coefficients([0.0, 0.012, -0.0095], [1.0, -1.93, 0.9305], nk=2)
    lowpass = LowPass(240.0, stages).tf(TS)
    baked = cascade(tf, lowpass)
    filtered = scipy.signal.lfilter(lowpass.b, lowpass.a, u)
    assert_allclose(
        scipy.signal.lfilter(baked.b, baked.a, u),
        scipy.signal.lfilter(tf.b, tf.a, filtered),
        rtol=1e-9,
        atol=1e-9,  # outputs of order 1; the two orders of summation differ by rounding
    )
    assert baked.static_gain() == pytest.approx(tf.static_gain(), rel=1e-9)
    assert baked.nk == tf.nk and baked.order == tf.order + stages


def test_match_recovers_the_time_constant_that_made_the_target():
    """On a target made by a low-pass on the grid, the match finds that low-pass with ~0 RMS."""
    rng = np.random.default_rng(3)
    raw = 20.0 + np.cumsum(rng.standard_normal(2000)) * 0.02 + 0.3 * rng.standard_normal(2000)
    taus = np.geomspace(20.0, 2000.0, 25)
    truth = LowPass(float(taus[11]), 2)
    matched = match_lowpass(raw, truth.apply(raw, TS), TS, taus_s=taus)
    assert matched.lowpass == truth
    assert matched.rms_degC < 1e-12 < matched.raw_rms_degC


def test_bad_low_pass_is_refused():
    """A non-positive time constant or a third stage is a ModelError naming the value."""
    with pytest.raises(ModelError, match="> 0 s"):
        LowPass(0.0)
    with pytest.raises(ModelError, match="1 or 2 stages"):
        LowPass(60.0, 3)
