"""MISO output-error identification: one denominator per input, fitted on the free-run error.

The model is MATLAB's ``oe`` structure::

    y(k) = sum_i  B_i(q) / F_i(q)  u_i(k - nk_i)  +  e(k)
    B_i = b_i0 + ... + b_i,nb_i-1 q^-(nb_i-1),     F_i = 1 + f_i1 q^-1 + ... + f_i,nf_i q^-nf_i

with ``y`` in um. The parameters minimise the *simulation* error
``||y - y_hat||`` (the free-run output from rest, what the daemon runs), not
the one-step prediction error of ARX, which with output noise and slow poles
is biased towards fast poles and a low simulation fit.

Levenberg-Marquardt with the analytic Jacobian of filtered regressors: with
``w_i = u_i / F_i`` and ``x_i = B_i w_i(k - nk_i)`` (the channel's output)::

    d y_hat / d b_ij = w_i(k - nk_i - j)          d y_hat / d f_ij = -v_i(k - j),   v_i = x_i / F_i

so an iteration costs two ``lfilter`` recursions per input. Two things make
it converge in a handful of iterations where a plain joint search crawls:

- *variable projection*: ``y_hat`` is linear in the ``b_ij`` once the ``F_i``
  are fixed, so every trial solves the numerators by least squares and the
  search runs over the denominators only (Kaufman's Jacobian, ``d y_hat/df``
  with the numerator directions projected out);
- the *difference basis* of :mod:`compd.model.arx` for the Jacobian columns
  (``Delta^j w_i(k - nk_i)``, ``Delta^j v_i(k - 1)``), in which slow filtered
  signals are not nearly collinear; steps map back to raw coefficients exactly.

The start is ARX refined by Steiglitz-McBride (:func:`steiglitz_mcbride`).
Every accepted iterate is :func:`admissible`: steps that leave the unit
circle are retried with more damping, and poles on the non-positive real
axis (no continuous-time equivalent) are projected back.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import scipy.signal

from compd.errors import ModelError
from compd.model.arx import (
    UNIT_CIRCLE_MARGIN,
    ArxParameters,
    build_regression,
    difference_matrix,
    differences,
    max_pole_magnitude,
    simulate_arx,
    solve_arx,
    solve_scaled,
)
from compd.model.metrics import fit_percent

#: Called with (iteration, fraction of the iteration budget used, current cost).
OeProgress = Callable[[int, float, float], None]


@dataclass(frozen=True, eq=False)  # eq=False: arrays have no single truth value
class OeParameters:
    """Per input: numerator ``b_i`` (nb_i), denominator ``f_i`` (nf_i + 1, ``f_i[0] = 1``), delay ``nk_i``."""

    b: tuple[np.ndarray, ...]
    f: tuple[np.ndarray, ...]
    nk: tuple[int, ...]

    def stable(self) -> bool:
        return all(max_pole_magnitude(f) < 1.0 - UNIT_CIRCLE_MARGIN for f in self.f)


@dataclass(frozen=True)
class OeResult:
    """The fitted model, its sum of squared simulation errors (um^2) and how the search ended."""

    parameters: OeParameters
    cost: float
    iterations: int
    converged: bool


def _difference_columns(x: np.ndarray, delay: int, count: int, out: np.ndarray) -> None:
    """``out[:, j] = Delta^j x(k - delay)`` with ``x`` zero before the record (the model starts at rest)."""
    padded = np.concatenate([np.zeros(delay + count - 1), x[: x.size - delay] if delay else x])
    differences(padded, 0, count, count - 1, out=out)


def simulate_oe(parameters: OeParameters, inputs: np.ndarray) -> np.ndarray:
    """Free-run output ``sum_i B_i q^-nk_i / F_i u_i`` from rest (um), one ``lfilter`` per input."""
    inputs = np.asarray(inputs, dtype=float)
    total = np.zeros(inputs.shape[0])
    for i, (b, f, nk) in enumerate(zip(parameters.b, parameters.f, parameters.nk, strict=True)):
        total += scipy.signal.lfilter(np.concatenate([np.zeros(nk), b]), f, inputs[:, i])
    return total


class _Evaluation:
    """One set of denominators: filtered inputs ``w_i``, the best numerators for them, the residual.

    Variable projection (Golub & Pereyra): ``y_hat`` is linear in the
    numerators once the denominators are fixed, so for every trial ``F`` the
    ``B_i`` are solved exactly by least squares and only the denominators are
    searched. This removes the gain/pole coupling that makes a joint search
    over ``b`` and ``f`` crawl when ``F(1)`` is ~1e-7 (poles of hours at 1 s).
    """

    def __init__(
        self,
        denominators: tuple[np.ndarray, ...],
        nb: Sequence[int],
        nk: Sequence[int],
        y: np.ndarray,
        inputs: np.ndarray,
        first_sample: int = 0,
    ) -> None:
        self.denominators = denominators
        self.first_sample = first_sample
        n_columns = sum(nb)
        regressors = np.empty((y.size, n_columns), order="F")
        self.filtered: list[np.ndarray] = []
        column = 0
        for i, (f, count, delay) in enumerate(zip(denominators, nb, nk, strict=True)):
            w = scipy.signal.lfilter([1.0], f, inputs[:, i])
            self.filtered.append(w)
            _difference_columns(w, delay, count, regressors[:, column : column + count])
            column += count
        # Filtered from sample 0 (the model runs from rest there); only later rows are fitted.
        self.regressors = regressors[first_sample:]
        self.gram = self.regressors.T @ self.regressors
        theta = solve_scaled(self.gram, self.regressors.T @ y[first_sample:])
        numerators, column = [], 0
        for count in nb:
            numerators.append(difference_matrix(count) @ theta[column : column + count])
            column += count
        self.parameters = OeParameters(tuple(numerators), denominators, tuple(nk))
        self.residual = y[first_sample:] - self.regressors @ theta
        self.cost = float(self.residual @ self.residual)

    def projected_normal_equations(self) -> tuple[np.ndarray, np.ndarray]:
        """``J^T J`` and ``J^T r`` of the projected residual (Kaufman's Jacobian) w.r.t. the denominators.

        ``J = -P_perp dy_hat/df`` with ``dy_hat/df_ij = -v_i(k-j)``, ``v_i = x_i / F_i``,
        in the difference basis; ``P_perp`` removes the span of the numerator
        regressors, so ``J^T J`` is a Schur complement of one Gram matrix.
        """
        p = self.parameters
        n_f = sum(f.size - 1 for f in p.f)
        sensitivity = np.empty((self.residual.size + self.first_sample, n_f), order="F")
        column = 0
        for b, f, nk, w in zip(p.b, p.f, p.nk, self.filtered, strict=True):
            nf = f.size - 1
            if nf:
                x = scipy.signal.lfilter(np.concatenate([np.zeros(nk), b]), [1.0], w)
                v = scipy.signal.lfilter([1.0], f, x)
                _difference_columns(v, 1, nf, sensitivity[:, column : column + nf])
                column += nf
        sensitivity = -sensitivity[self.first_sample :]
        cross = self.regressors.T @ sensitivity
        projected = sensitivity.T @ sensitivity - cross.T @ solve_scaled(self.gram, cross)
        return projected, sensitivity.T @ self.residual


#: Where a pole on the non-positive real axis is moved: the nearest admissible
#: place that is not ``z = 0`` (a time constant of 0.14 samples, i.e. no dynamics).
_BOUNDARY_POLE = 1e-3


def admissible(f: np.ndarray) -> bool:
    """Stable, and the ZOH equivalent of a continuous system: no pole on the non-positive real axis.

    A sampled thermal system never has such poles; one that appears in a fit
    (typically where a pole and a zero nearly cancel) would make the model
    impossible to convert to another sample time (see
    :func:`compd.model.transfer.continuous_equivalent`), so the search keeps out.
    """
    if f.size <= 1:
        return True
    poles = np.roots(f)
    if np.max(np.abs(poles)) >= 1.0 - UNIT_CIRCLE_MARGIN:
        return False
    on_axis = np.abs(poles.imag) <= 1e-12 * np.maximum(1.0, np.abs(poles.real))
    return not bool(np.any(on_axis & (poles.real <= 0.0)))


def _sampled_continuous(f: np.ndarray) -> np.ndarray:
    """``f`` with poles on the non-positive real axis moved to :data:`_BOUNDARY_POLE`.

    The projection onto the admissible set that keeps the search inside it
    (a projected Levenberg-Marquardt step): such a pole only ever appears
    where a pole and a zero nearly cancel, so moving it changes little, and
    the step is still accepted only if it lowers the simulation error.
    """
    if admissible(f):
        return f
    poles = np.roots(f)
    on_axis = np.abs(poles.imag) <= 1e-12 * np.maximum(1.0, np.abs(poles.real))
    poles = np.where(on_axis & (poles.real <= 0.0), _BOUNDARY_POLE, poles)
    return np.real(np.poly(poles))


def _basis_map(denominators: tuple[np.ndarray, ...]) -> np.ndarray:
    """Block-diagonal map from difference-basis steps to raw denominator coefficient steps."""
    sizes = [f.size - 1 for f in denominators]
    matrix = np.zeros((sum(sizes), sum(sizes)))
    position = 0
    for n in sizes:
        matrix[position : position + n, position : position + n] = difference_matrix(n)
        position += n
    return matrix


def _stepped(denominators: tuple[np.ndarray, ...], step: np.ndarray) -> tuple[np.ndarray, ...]:
    out, position = [], 0
    for f in denominators:
        n = f.size - 1
        out.append(np.concatenate([[1.0], f[1:] + step[position : position + n]]))
        position += n
    return tuple(out)


def fit_oe(
    y: np.ndarray,
    inputs: np.ndarray,
    initial: OeParameters,
    *,
    max_iterations: int = 50,
    tolerance: float = 1e-6,
    progress: OeProgress | None = None,
    first_sample: int = 0,
) -> OeResult:
    """Refine ``initial``'s denominators (stable) by Levenberg-Marquardt on the free-run error.

    The free-run output is simulated from rest at sample 0; only its errors
    from ``first_sample`` on count (the fit of a later part of a record).

    The numerators are solved exactly for every trial (variable projection);
    ``initial.b`` only fixes their sizes. Every accepted denominator is
    :func:`admissible`: poles that a start or a step puts on the non-positive
    real axis are projected back (:func:`_sampled_continuous`), and steps
    that leave the unit circle are retried with more damping. Stops when a step lowers the cost by
    less than ``tolerance`` relative, when more damping finds no better stable
    step, or after ``max_iterations`` Jacobians.
    """
    y = np.asarray(y, dtype=float)
    inputs = np.asarray(inputs, dtype=float).reshape(y.size, -1)
    if not initial.stable():
        raise ModelError(
            "the starting model for the output-error fit is unstable; start from a stable "
            "ARX model (lower order or --order auto)"
        )
    nb = [b.size for b in initial.b]
    start = tuple(_sampled_continuous(f) for f in initial.f)
    current = _Evaluation(start, nb, initial.nk, y, inputs, first_sample)
    to_raw = _basis_map(initial.f)
    damping = 1e-4
    converged = False
    iteration = 0
    if to_raw.size == 0:  # every nf_i = 0: a FIR model, solved exactly already
        return OeResult(current.parameters, current.cost, 0, True)
    for iteration in range(1, max_iterations + 1):
        hessian, gradient = current.projected_normal_equations()
        diagonal = np.diag(hessian).copy()
        diagonal[diagonal <= 0.0] = 1.0
        improved, relative_gain = False, 0.0
        while damping < 1e10:
            step = to_raw @ _damped_step(hessian, gradient, diagonal, damping)
            denominators = _stepped(current.denominators, step)
            denominators = tuple(_sampled_continuous(f) for f in denominators)
            if all(admissible(f) for f in denominators):
                trial = _Evaluation(denominators, nb, initial.nk, y, inputs, first_sample)
                if trial.cost < current.cost:
                    relative_gain = (current.cost - trial.cost) / max(current.cost, 1e-300)
                    current = trial
                    damping = max(damping / 10.0, 1e-12)
                    improved = True
                    break
            damping *= 10.0
        if progress is not None:
            progress(iteration, iteration / max_iterations, current.cost)
        if not improved or relative_gain < tolerance:
            converged = True
            break
    return OeResult(current.parameters, current.cost, iteration, converged)


def _damped_step(
    hessian: np.ndarray, gradient: np.ndarray, diagonal: np.ndarray, damping: float
) -> np.ndarray:
    """Marquardt's step ``(H + lambda diag(H)) d = g``, solved after scaling to unit diagonal."""
    scale = np.sqrt(diagonal)
    scaled = hessian / scale[:, None] / scale[None, :]
    scaled[np.diag_indices_from(scaled)] += damping
    step = np.linalg.lstsq(scaled, gradient / scale, rcond=1e-14)[0] / scale
    return np.asarray(step)


def oe_from_arx(
    a: np.ndarray, b: Sequence[np.ndarray], nk: Sequence[int], nf: Sequence[int]
) -> OeParameters:
    """An OE starting point from an ARX fit: every ``F_i = A`` (``len(a) - 1`` must equal each ``nf_i``)."""
    if any(n != a.size - 1 for n in nf):
        raise ModelError("the ARX start must have na equal to every nf_i")
    return OeParameters(
        tuple(np.asarray(x, dtype=float).copy() for x in b),
        tuple(np.asarray(a, dtype=float).copy() for _ in b),
        tuple(int(d) for d in nk),
    )


def steiglitz_mcbride(
    y: np.ndarray,
    inputs: np.ndarray,
    start: ArxParameters,
    *,
    iterations: int = 5,
    first_sample: int = 0,
) -> ArxParameters:
    """A common-denominator output-error estimate by Steiglitz-McBride iteration, from ``start``.

    Repeats: filter ``y`` and every ``u_i`` by ``1/A`` of the last estimate and
    fit ARX of the same orders to the filtered data. At a fixed point the
    equation error is the simulation error, so unlike ARX it is not biased by
    output noise; it gives :func:`fit_oe` a start close to the optimum (the
    remaining step is separating the denominators). Samples before
    ``first_sample`` are filtered and simulated but not fitted. Stops early when an
    iterate is unstable or stops improving the free-run fit; returns the best.
    """
    y = np.asarray(y, dtype=float)
    inputs = np.asarray(inputs, dtype=float).reshape(y.size, -1)
    na = start.a.size - 1
    nb = [b.size for b in start.b]
    scored = y[first_sample:]
    best, best_fit = start, fit_percent(scored, simulate_arx(start, inputs)[first_sample:])
    current = start
    for _ in range(iterations):
        filtered_y = scipy.signal.lfilter([1.0], current.a, y)
        filtered_u = scipy.signal.lfilter([1.0], current.a, inputs, axis=0)
        regression, _ = build_regression(
            filtered_y,
            filtered_u,
            na_max=na,
            nb_max=max(nb),
            delays=sorted(set(start.nk)),
            first_sample=first_sample,
        )
        current = solve_arx(regression, na, nb, start.nk)
        if not current.stable():
            break
        fit = fit_percent(scored, simulate_arx(current, inputs)[first_sample:])
        if not fit > best_fit + 1e-6:
            if fit > best_fit:
                best = current
            break
        best, best_fit = current, fit
    return best
