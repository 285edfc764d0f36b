"""Transfer functions: the papers' forms, exact ZOH discretisation, refusal of unrunnable models."""

import numpy as np
import pytest
import scipy.signal
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.testing import assert_allclose

from compd.errors import ModelError
from compd.model.transfer import (
    ContinuousTF,
    DiscreteTF,
    continuous_equivalent,
    polynomial_roots,
    resample_discrete,
)

# Horejs 2010 eq. 2 and 3, coefficients in ascending powers of s as printed.
E_Z_HEAT = ContinuousTF.from_coefficients([0.0162, 10.74, 5.368], [0.002098, 2.379, 1.0])
E_ETVE = ContinuousTF.from_coefficients(
    [4.028e-10, 1.491e-7, 0.0002884, 0.0002421, 4.895e-5],
    [4.02e-10, 1.181e-6, 0.001166, 0.01072, 1.0],
)


@pytest.mark.parametrize("tf", [E_Z_HEAT, E_ETVE], ids=["E_z_heat", "E_ETVE"])
@pytest.mark.parametrize("sample_time_s", [1.0, 15.0, 60.0])
def test_zoh_matches_scipy_cont2discrete(tf: ContinuousTF, sample_time_s: float) -> None:
    """Discretising a Horejs 2010 TF gives scipy's cont2discrete(zoh) coefficients to 1e-9 relative."""
    num, den, _ = scipy.signal.cont2discrete(
        (tf.num[::-1], tf.den[::-1]), sample_time_s, method="zoh"
    )
    num, den = np.squeeze(num) / den[0], den / den[0]
    discrete = tf.discretise(sample_time_s)
    # compd drops exactly-zero trailing coefficients (at 60 s a pole of e^-142 underflows).
    compd_num = np.pad(discrete.num, (0, num.size - len(discrete.num)))
    compd_den = np.pad(discrete.den, (0, den.size - len(discrete.den)))
    assert_allclose(compd_num, num, rtol=1e-9, atol=1e-9 * np.max(np.abs(num)))
    assert_allclose(compd_den, den, rtol=1e-9, atol=1e-12)


def test_zoh_keeps_the_static_gain_and_time_constants() -> None:
    """E_z_heat discretised at 1 s keeps K1/T1 = 7.72 um/K and its 1134 s and 0.42 s time constants."""
    discrete = E_Z_HEAT.discretise(1.0)
    assert discrete.static_gain() == pytest.approx(0.0162 / 0.002098, rel=1e-9)
    slow, fast = discrete.time_constants_s(1.0)
    assert_allclose(
        sorted([-1 / p.real for p in E_Z_HEAT.poles()], reverse=True), [slow, fast], rtol=1e-9
    )


def test_discrete_tf_is_normalised_so_a0_is_one() -> None:
    """A difference equation with a0 != 1 (Horejs 2015 eq. 1 divides by b0) is normalised at construction."""
    tf = DiscreteTF.from_coefficients([0.0, 0.2], [2.0, -1.8])
    assert tf.den == (1.0, -0.9)
    assert tf.num == (0.0, 0.1)
    assert tf.static_gain() == pytest.approx(1.0)


def test_input_delay_is_folded_into_the_numerator() -> None:
    """nk samples of input delay become nk leading zeros of b."""
    tf = DiscreteTF.from_coefficients([0.5], [1.0, -0.5], nk=3)
    assert tf.b.tolist() == [0.0, 0.0, 0.0, 0.5]


def test_non_causal_discrete_tf_is_refused() -> None:
    """a0 == 0 means y(k) depends on the future: refused with a message saying so."""
    with pytest.raises(ModelError, match="non-causal"):
        DiscreteTF.from_coefficients([1.0], [0.0, 1.0])


@pytest.mark.parametrize("den", [[1.0, -1.01], [1.0, -1.0], [1.0, 0.0, 1.21]])
def test_unstable_or_marginal_discrete_tf_is_refused(den: list[float]) -> None:
    """A pole on or outside the unit circle is refused and the message gives the pole."""
    tf = DiscreteTF.from_coefficients([0.1], den)
    with pytest.raises(ModelError, match=r"unstable: pole at z = .*outside"):
        tf.check_stable()


def test_unstable_continuous_tf_is_refused_with_a_hint_on_power_order() -> None:
    """A right-half-plane pole (often a descending list read as ascending) names the power order."""
    tf = ContinuousTF.from_coefficients([1.0], [-0.5, 1.0])
    with pytest.raises(ModelError, match="ascending powers of s"):
        tf.check_stable()


def test_improper_continuous_tf_is_refused() -> None:
    """A numerator of higher degree than the denominator is non-causal."""
    with pytest.raises(ModelError, match="improper"):
        ContinuousTF.from_coefficients([1.0, 1.0, 1.0], [1.0, 1.0])


def test_zero_highest_power_denominator_coefficient_is_refused() -> None:
    """The leading coefficient of D(s) may not be zero: the order would be ambiguous."""
    with pytest.raises(ModelError, match="highest-power coefficient"):
        ContinuousTF.from_coefficients([1.0], [1.0, 2.0, 0.0])


def test_non_finite_coefficients_are_refused() -> None:
    """NaN or inf in a coefficient list is an error, not a silently broken model."""
    with pytest.raises(ModelError, match="non-finite"):
        DiscreteTF.from_coefficients([float("nan")], [1.0])


@pytest.mark.parametrize("tf", [E_Z_HEAT, E_ETVE], ids=["E_z_heat", "E_ETVE"])
def test_discrete_model_converts_exactly_to_another_sample_time(tf: ContinuousTF) -> None:
    """A 1 s ZOH model converted to 15 s equals the 15 s ZOH model of the same plant."""
    converted = resample_discrete(tf.discretise(1.0), 1.0, 15.0)
    direct = tf.discretise(15.0)
    assert_allclose(converted.den, direct.den, rtol=1e-7, atol=1e-9)
    assert_allclose(converted.num, direct.num, rtol=1e-5, atol=1e-7 * np.max(np.abs(direct.num)))
    assert converted.static_gain() == pytest.approx(direct.static_gain(), rel=1e-5)


def test_conversion_keeps_whole_sample_delays() -> None:
    """An ARX model with nk = 3 at 1 s keeps its 2 s of pure delay (nk = 1 is the hold itself)."""
    tf = DiscreteTF.from_coefficients([0.01], [1.0, -0.99], nk=3)
    back = continuous_equivalent(tf, 1.0)
    assert back.delay_s == 2.0
    assert_allclose(back.discretise(1.0).b, tf.b, atol=1e-12)


def test_conversion_without_continuous_equivalent_is_refused() -> None:
    """A pole on the negative real axis has no real continuous equivalent: refused, not approximated."""
    tf = DiscreteTF.from_coefficients([0.0, 0.5], [1.0, 0.5])
    with pytest.raises(ModelError, match="no continuous-time"):
        resample_discrete(tf, 1.0, 10.0)


def test_delay_that_is_not_a_whole_number_of_samples_is_refused() -> None:
    """A 5 s delay cannot be run at 2 s sampling without changing the model."""
    tf = ContinuousTF.from_coefficients([1.0], [1.0, 100.0], delay_s=5.0)
    with pytest.raises(ModelError, match="whole number"):
        tf.discretise(2.0)


def test_static_gain_with_delay_converts_between_sample_times() -> None:
    """A delayed static gain (the controller's regression, order 0) converts to a coarser rate exactly."""
    tf = DiscreteTF.from_coefficients([7.0], [1.0], nk=10)
    converted = resample_discrete(tf, 1.0, 5.0)
    assert converted.b.tolist() == [0.0, 0.0, 7.0]


def test_fir_of_several_taps_is_not_converted() -> None:
    """A moving average over samples has no continuous equivalent: refused."""
    with pytest.raises(ModelError, match="FIR"):
        resample_discrete(DiscreteTF.from_coefficients([0.5, 0.5], [1.0]), 1.0, 10.0)


def test_trailing_zero_coefficients_add_no_poles() -> None:
    """den: [1, -0.9, 0] is the first-order TF of [1, -0.9], not a second pole at z = 0."""
    tf = DiscreteTF.from_coefficients([0.1, 0.0], [1.0, -0.9, 0.0])
    assert tf.order == 1 and tf.num == (0.1,)


def test_a_static_continuous_gain_stays_static() -> None:
    """K over 1 (order 0) discretises to the same gain with no dynamics."""
    tf = ContinuousTF.from_coefficients([7.0], [1.0]).discretise(10.0)
    assert (tf.num, tf.den) == ((7.0,), (1.0,))


coefficient = st.one_of(
    st.just(0.0),
    st.floats(min_value=-1e6, max_value=1e6, allow_nan=False).filter(lambda x: abs(x) > 1e-6),
)


@settings(max_examples=400, deadline=None)
@given(st.lists(coefficient, min_size=1, max_size=5))
def test_the_written_out_roots_are_numpys_in_its_order(coefficients: list[float]) -> None:
    """Up to degree two the roots are written out (no LAPACK in the daemon): numpy's, in its order and dtype."""
    expected = np.roots(coefficients)
    got = polynomial_roots(np.array(coefficients))
    assert got.shape == expected.shape
    assert np.iscomplexobj(got) == np.iscomplexobj(expected) or np.all(expected.imag == 0)
    scale = max(1.0, float(np.abs(expected).max(initial=0.0)))
    assert_allclose(got, expected, rtol=1e-8, atol=1e-10 * scale)


def test_a_repeated_pole_is_real_and_the_order_is_numpys() -> None:
    """(z - 0.9)^2: two real poles at 0.9, and a quadratic's larger root first, as numpy orders them."""
    repeated = polynomial_roots(np.array([1.0, -1.8, 0.81]))
    assert not np.iscomplexobj(repeated), repeated
    assert_allclose(repeated, [0.9, 0.9])
    assert_allclose(
        polynomial_roots(np.array([1.0, -1.0528, 0.0687])), np.roots([1.0, -1.0528, 0.0687])
    )
