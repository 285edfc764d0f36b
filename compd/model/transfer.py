"""Transfer functions in the two forms the papers print, and the exact map between them.

A *discrete* TF is the difference equation of Horejs 2015 eq. 1 / Post-process 2024 eq. 3::

    y(k) = [b0 u(k-nk) + b1 u(k-nk-1) + ... + bn u(k-nk-n)
            - a1 y(k-1) - ... - am y(k-m)] / a0

i.e. ``B(z^-1) / A(z^-1)`` with coefficients in ascending powers of ``z^-1``
and an input delay of ``nk`` samples.

A *continuous* TF is the ratio of polynomials in ``s`` that Horejs 2010 eq. 2
and 3 print in ascending powers (``K1 + K2 s + K3 s^2`` over
``T1 + T2 s + TD1 s^2``). It becomes a discrete TF by zero-order hold at the
model's sample time, which is exact for inputs held constant between samples
(what a 1 Hz sampler delivers).

Everything here is pure numerics: numpy and scipy, no files, no logging.
scipy is imported only by the conversions between the two forms (and from
one sample time to another): poles (``np.roots``), gains and stability need
numpy alone, so the daemon, given discrete TFs at its loop period, never
loads scipy's ~100 MB.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from compd.errors import ModelError
from compd.model.limits import MAX_DELAY_SAMPLES, MAX_ORDER

#: A discrete pole this close to the unit circle (or beyond) is refused: its
#: time constant would exceed ~30 years at 1 s sampling, which is an integrator
#: in all but name and has no steady state to start from.
_UNIT_CIRCLE_MARGIN = 1e-9


@contextmanager
def _quiet_conversions() -> Iterator[None]:
    """scipy warns when a converted numerator has ~1e-17 leading terms; they are rounding, not a fault.

    A singular matrix logarithm warns too: its result is not finite, which the
    conversion then refuses as a ModelError (the message a user reads).
    """
    import scipy.signal  # see the module's docstring: only conversions load scipy

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", scipy.signal.BadCoefficients)
        warnings.filterwarnings("ignore", message="The logm input matrix is exactly singular")
        yield


@contextmanager
def _numerics(what: str) -> Iterator[None]:
    """Failures on extreme coefficients (overflow, a singular matrix) as a ModelError."""
    try:
        with np.errstate(all="ignore"):
            yield
    except (ArithmeticError, ValueError, np.linalg.LinAlgError) as exc:
        raise ModelError(
            f"{what} failed ({type(exc).__name__}): the coefficients span too many orders of "
            "magnitude for the sample time. Rescale the TF or check its coefficients"
        ) from exc


def polynomial_roots(coefficients: np.ndarray) -> np.ndarray:
    """The roots of a polynomial (descending powers) as :func:`numpy.roots` gives them.

    Up to degree two, written out: the daemon's models are mostly of first and
    second order, and ``numpy.roots`` (an eigenvalue problem) touches LAPACK's
    eigen-solver, about 0.9 MB resident that a daemon otherwise never uses.
    Higher degrees, and coefficients the closed form would overflow, go to
    ``numpy.roots``.
    """
    c = np.trim_zeros(np.asarray(coefficients, dtype=float), "f")
    zeros_at_origin = len(c) - len(np.trim_zeros(c, "b"))
    c = np.trim_zeros(c, "b")
    if len(c) > 3 or len(c) == 0 or not np.all(np.isfinite(c)):
        return np.roots(coefficients)
    with np.errstate(all="ignore"):
        p = c[1:] / c[0]
        if len(p) == 0:
            roots = np.zeros(0)
        elif len(p) == 1:
            roots = np.array([-p[0]])
        else:
            half_b, q = p[0] / 2.0, p[1]
            disc = half_b * half_b - q
            if not np.isfinite(disc):
                return np.roots(coefficients)
            if disc >= 0.0:
                # The larger root first without cancellation, the other from the product (Vieta).
                big = -half_b - np.copysign(np.sqrt(disc), half_b)
                roots = np.array([big, q / big]) if big != 0.0 else np.zeros(2)
            else:
                roots = np.array(
                    [complex(-half_b, np.sqrt(-disc)), complex(-half_b, -np.sqrt(-disc))]
                )
    return np.concatenate([roots, np.zeros(zeros_at_origin, dtype=roots.dtype)])


def _as_coefficients(values: object, what: str) -> np.ndarray:
    array = np.asarray(values, dtype=float)
    if array.ndim != 1 or array.size == 0:
        raise ModelError(f"{what} must be a non-empty list of numbers")
    if array.size > MAX_ORDER + 1:
        raise ModelError(
            f"{what} has {array.size} coefficients; compd runs TFs up to order {MAX_ORDER} "
            f"({MAX_ORDER + 1} coefficients)"
        )
    if not np.all(np.isfinite(array)):
        raise ModelError(f"{what} contains a non-finite coefficient: {array.tolist()}")
    return array


@dataclass(frozen=True)
class DiscreteTF:
    """``B(z^-1) / A(z^-1)`` with input delay ``nk`` samples, normalised so ``a[0] == 1``.

    Parameters
    ----------
    num, den
        Coefficients in ascending powers of ``z^-1`` (``b0, b1, ...``; ``a0, a1, ...``).
    nk
        Input delay in samples (Horejs 2015 eq. 1's ``k-n``), >= 0.
    """

    num: tuple[float, ...]
    den: tuple[float, ...]
    nk: int = 0

    @classmethod
    def from_coefficients(cls, num: object, den: object, nk: int = 0) -> DiscreteTF:
        """Build a causal, normalised TF; refuse ``a0 == 0`` (non-causal) and bad delays."""
        b = _as_coefficients(num, "num")
        a = _as_coefficients(den, "den")
        if a[0] == 0.0:
            raise ModelError(
                "den[0] (the coefficient of z^0 in the denominator) is 0, so y(k) would depend "
                "on future samples: the model is non-causal. Give den in ascending powers of "
                "z^-1 starting with a non-zero a0"
            )
        if int(nk) != nk or nk < 0:
            raise ModelError(f"nk (input delay in samples) must be a whole number >= 0, got {nk}")
        if nk > MAX_DELAY_SAMPLES:
            raise ModelError(
                f"input delay of {nk:g} samples exceeds the {MAX_DELAY_SAMPLES} compd runs"
            )
        # Trailing zero coefficients carry nothing and would add spurious poles at z = 0.
        b = np.trim_zeros(b, "b") if np.any(b) else b[:1]
        a = np.trim_zeros(a, "b")
        with np.errstate(all="ignore"):
            b, a = b / a[0], a / a[0]
        if not (np.all(np.isfinite(b)) and np.all(np.isfinite(a))):
            raise ModelError(
                "normalising by den[0] overflows: the coefficients span too many orders of "
                "magnitude. Rescale num and den"
            )
        return cls(num=tuple(b), den=tuple(a), nk=int(nk))

    @property
    def b(self) -> np.ndarray:
        """Numerator with the input delay folded in as leading zeros."""
        return np.concatenate([np.zeros(self.nk), np.asarray(self.num)])

    @property
    def a(self) -> np.ndarray:
        return np.asarray(self.den)

    @property
    def order(self) -> int:
        """Number of denominator lags (the TF's order, Post-process 2024's ``m``)."""
        return len(self.den) - 1

    def poles(self) -> np.ndarray:
        """Poles in the z-plane (roots of ``z^m A(z^-1)``)."""
        if not self.order:
            return np.zeros(0, dtype=complex)
        with _numerics("finding the poles"):
            return polynomial_roots(np.asarray(self.den))

    def static_gain(self) -> float:
        """Output per unit of constant input at steady state: ``B(1) / A(1)`` (inf if it overflows)."""
        with np.errstate(all="ignore"):
            return float(np.sum(self.num) / np.sum(self.den))

    def time_constants_s(self, sample_time_s: float) -> np.ndarray:
        """Time constants of the real-axis and complex poles, ``-Ts / ln|p|``, in seconds."""
        magnitudes = np.abs(self.poles())
        magnitudes = magnitudes[magnitudes > 0.0]
        return np.sort(-sample_time_s / np.log(magnitudes))[::-1]

    def check_stable(self) -> None:
        """Refuse a TF with a pole on or outside the unit circle."""
        poles = self.poles()
        if poles.size and np.max(np.abs(poles)) >= 1.0 - _UNIT_CIRCLE_MARGIN:
            worst = poles[np.argmax(np.abs(poles))]
            raise ModelError(
                f"unstable: pole at z = {worst:.9g} (|z| = {abs(worst):.9g}) lies on or outside "
                "the unit circle, so the output would grow without bound. Re-identify the model "
                "or check the sign and order of den"
            )


@dataclass(frozen=True)
class ContinuousTF:
    """``N(s) / D(s)`` with coefficients in ascending powers of ``s`` (Horejs 2010 eq. 2, 3).

    ``delay_s`` is a pure input delay, which must be a whole number of samples
    when the TF is discretised.
    """

    num: tuple[float, ...]
    den: tuple[float, ...]
    delay_s: float = 0.0

    @classmethod
    def from_coefficients(cls, num: object, den: object, delay_s: float = 0.0) -> ContinuousTF:
        """Build a proper TF; refuse a zero highest-power denominator coefficient and improper TFs."""
        n = _as_coefficients(num, "num")
        d = _as_coefficients(den, "den")
        if d[-1] == 0.0:
            raise ModelError(
                f"den's highest-power coefficient (of s^{d.size - 1}) is 0: the model's order is "
                "ill-defined. Drop the trailing zero or give the coefficient"
            )
        n_trimmed = np.trim_zeros(n, "b")
        if n_trimmed.size > d.size:
            raise ModelError(
                f"improper (non-causal): numerator degree {n_trimmed.size - 1} exceeds "
                f"denominator degree {d.size - 1}"
            )
        if not np.isfinite(delay_s) or delay_s < 0:
            raise ModelError(f"delay_s must be >= 0 seconds, got {delay_s}")
        with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
            scaled = d / d[-1]  # the overflow is the finding, said below
        if not np.all(np.isfinite(scaled)):
            raise ModelError(
                "den's coefficients span too many orders of magnitude (dividing by the "
                "highest-power one overflows). Rescale the TF"
            )
        return cls(num=tuple(n), den=tuple(d), delay_s=float(delay_s))

    def poles(self) -> np.ndarray:
        """Poles in the s-plane, in rad/s."""
        if len(self.den) == 1:
            return np.zeros(0, dtype=complex)
        with _numerics("finding the poles"):
            return polynomial_roots(np.asarray(self.den[::-1]))

    def static_gain(self) -> float:
        """``N(0) / D(0)``: output per unit of constant input at steady state."""
        if self.den[0] == 0.0:
            raise ModelError("den[0] is 0: the TF has an integrator and no static gain")
        return self.num[0] / self.den[0]

    def check_stable(self) -> None:
        """Refuse a TF with a pole in the closed right half-plane."""
        poles = self.poles()
        if poles.size and np.max(poles.real) >= 0.0:
            worst = poles[np.argmax(poles.real)]
            raise ModelError(
                f"unstable: pole at s = {worst:.6g} 1/s is not in the left half-plane. "
                "Check the power order (compd reads ascending powers of s: K1 + K2 s + ...)"
            )

    def discretise(self, sample_time_s: float) -> DiscreteTF:
        """Zero-order-hold equivalent at ``sample_time_s`` (same result as ``cont2discrete(method='zoh')``).

        Computed as ``Phi = expm([[A, B], [0, 0]] Ts)`` on a controllable
        state-space realisation, then converted back to a TF in ``z^-1``.
        """
        nk = _whole_samples(self.delay_s, sample_time_s)
        num_desc = np.asarray(self.num[::-1])
        den_desc = np.asarray(self.den[::-1])
        if len(self.den) == 1:  # a static gain
            return DiscreteTF.from_coefficients([self.num[0] / self.den[0]], [1.0], nk)
        import scipy.linalg  # see the module's docstring: only conversions load scipy
        import scipy.signal

        with _numerics(f"discretising at {sample_time_s:g} s"), _quiet_conversions():
            a_c, b_c, c_c, d_c = scipy.signal.tf2ss(num_desc, den_desc)
            n_states = a_c.shape[0]
            block = np.zeros((n_states + 1, n_states + 1))
            block[:n_states, :n_states] = a_c
            block[:n_states, n_states:] = b_c
            phi = scipy.linalg.expm(block * sample_time_s)
            a_d = phi[:n_states, :n_states]
            b_d = phi[:n_states, n_states:]
            if not np.all(np.isfinite(phi)):
                raise ArithmeticError("the matrix exponential overflows")
            num_z, den_z = scipy.signal.ss2tf(a_d, b_d, c_c, d_c)
        # ss2tf returns descending powers of z with equal lengths, which are
        # exactly the ascending powers of z^-1 once divided by z^n.
        return DiscreteTF.from_coefficients(np.atleast_2d(num_z)[0], den_z, nk)


def _whole_samples(delay_s: float, sample_time_s: float) -> int:
    samples = delay_s / sample_time_s
    if samples > MAX_DELAY_SAMPLES:
        raise ModelError(
            f"delay_s = {delay_s:g} s is {samples:g} samples of {sample_time_s:g} s; compd runs "
            f"delays up to {MAX_DELAY_SAMPLES} samples"
        )
    if abs(samples - round(samples)) > 1e-9 * max(1.0, samples):
        raise ModelError(
            f"delay_s = {delay_s} s is not a whole number of {sample_time_s} s samples; "
            "choose a delay that is a multiple of the sample time"
        )
    return round(samples)


def continuous_equivalent(tf: DiscreteTF, sample_time_s: float) -> ContinuousTF:
    """The continuous TF whose ZOH discretisation at ``sample_time_s`` is ``tf`` (exact d2c).

    Uses the matrix logarithm of the ZOH block matrix. Refused when no real
    continuous equivalent exists (a pole at z = 0 or on the negative real
    axis), in which case the model must be re-identified at the data's rate.
    """
    if tf.order == 0:
        return _static_equivalent(tf, sample_time_s)
    poles = tf.poles()
    if poles.size and np.any(
        (np.abs(poles) < 1e-12) | ((poles.real <= 0) & (np.abs(poles.imag) < 1e-12))
    ):
        raise ModelError(
            "has a pole at z = 0 or on the negative real axis, so it has no continuous-time "
            "equivalent and cannot be converted to another sample time. Resample the data to "
            f"the model's sample time ({sample_time_s} s) or re-identify at the data's rate"
        )
    # A ZOH equivalent of a strictly proper system starts with b0 = 0 (the
    # sample-and-hold lag, ARX's nk = 1); only leading zeros beyond that one
    # are a pure delay of whole samples.
    b = tf.b
    leading_zeros = int(np.argmax(b != 0.0)) if np.any(b != 0.0) else 0
    delay_samples = max(leading_zeros - 1, 0)
    import scipy.linalg  # see the module's docstring: only conversions load scipy
    import scipy.signal

    with _numerics("converting to continuous time"), _quiet_conversions():
        a_d, b_d, c_d, d_d = scipy.signal.tf2ss(*_padded(b[delay_samples:], tf.a))
        n_states = a_d.shape[0]
        block = np.eye(n_states + 1)
        block[:n_states, :n_states] = a_d
        block[:n_states, n_states:] = b_d
        log_block = scipy.linalg.logm(block) / sample_time_s
    if np.max(np.abs(np.imag(log_block))) > 1e-9 * max(1.0, np.max(np.abs(log_block))):
        raise ModelError("has no real continuous-time equivalent; re-identify at the data's rate")
    log_block = np.real(log_block)
    with _quiet_conversions():
        num_s, den_s = scipy.signal.ss2tf(
            log_block[:n_states, :n_states], log_block[:n_states, n_states:], c_d, d_d
        )
    num_s = np.atleast_2d(num_s)[0]
    return ContinuousTF.from_coefficients(num_s[::-1], den_s[::-1], delay_samples * sample_time_s)


def _static_equivalent(tf: DiscreteTF, sample_time_s: float) -> ContinuousTF:
    """A static gain, possibly delayed; a FIR of several taps has no continuous equivalent."""
    taps = np.flatnonzero(tf.b)
    if taps.size > 1:
        raise ModelError(
            "is a moving average of several samples (FIR), which has no continuous-time "
            "equivalent. Resample the data to the model's sample time or re-identify"
        )
    delay = int(taps[0]) if taps.size else 0
    return ContinuousTF.from_coefficients([float(tf.b[delay])], [1.0], delay * sample_time_s)


def _padded(num: np.ndarray, den: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Equal-length coefficient arrays (ascending z^-1 powers are descending z powers then)."""
    size = max(num.size, den.size)
    return np.pad(num, (0, size - num.size)), np.pad(den, (0, size - den.size))


def resample_discrete(tf: DiscreteTF, from_s: float, to_s: float) -> DiscreteTF:
    """Exact conversion of a discrete TF to another sample time (d2c, then ZOH c2d)."""
    if from_s == to_s:
        return tf
    return continuous_equivalent(tf, from_s).discretise(to_s)
