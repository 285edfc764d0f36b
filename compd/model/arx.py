"""MISO ARX by least squares, conditioned for thermal time constants of hours at 1 Hz.

The model is Horejs 2015 eq. 1 / Pahk 2002 eq. 4 with one denominator shared by
all inputs (MATLAB's ``arx``)::

    A(q) y(k) = sum_i B_i(q) u_i(k - nk_i) + e(k)
    A = 1 + a_1 q^-1 + ... + a_na q^-na,   B_i = b_i0 + b_i1 q^-1 + ... + b_i,nb_i-1 q^-(nb_i-1)

so input ``i`` reaches the output through ``B_i q^-nk_i / A``. ``y`` in um and
each ``u_i`` in its own unit, both as changes from the start of the record.

Why not regress on the raw lags: with a time constant ``tau`` of an hour at
1 s sampling, ``y(k-1)`` and ``y(k-2)`` differ by ~``1/tau`` of their size, so
the raw regressor matrix has a condition number of ~1e4 per extra lag and its
normal equations ~1e8 (1e16 at third order: nothing left). compd regresses on
the *backward differences* instead (the delta-operator basis)::

    Delta^j x(k - d),   j = 0 .. n-1,      Delta x(k) = x(k) - x(k-1)

which span exactly the same space as ``x(k-d) .. x(k-d-n+1)`` but are close to
orthogonal for slow signals, with the target ``Delta y(k)``. The normal
equations are formed once from these columns (Gram matrix), scaled to unit
diagonal and solved; the binomial map back to raw lag coefficients is exact
integer arithmetic. Lower orders are leading sub-blocks of the same Gram
matrix, which is what makes the automatic order search
(:mod:`compd.model.orders`) cheap.
"""

from __future__ import annotations

import functools
import operator
from collections.abc import Sequence
from dataclasses import dataclass
from math import comb

import numpy as np
import scipy.linalg
import scipy.signal

from compd.errors import ModelError
from compd.model.experiments import ONE, each, spans

#: Poles this close to the unit circle are refused (as in DiscreteTF.check_stable).
UNIT_CIRCLE_MARGIN = 1e-9


def difference_matrix(n: int) -> np.ndarray:
    """``T`` with ``x(k-d-m) = ...``: column ``j`` holds the lag weights of ``Delta^j x(k-d)``.

    ``Delta^j x(k-d) = sum_m (-1)^m C(j, m) x(k-d-m)``, so coefficients ``c``
    on the difference columns are ``T @ c`` on the raw lags ``m = 0 .. n-1``.
    """
    matrix = np.zeros((n, n))
    for j in range(n):
        for m in range(j + 1):
            matrix[m, j] = (-1.0) ** m * comb(j, m)
    return matrix


def differences(
    x: np.ndarray, delay: int, count: int, first_row: int, out: np.ndarray | None = None
) -> np.ndarray:
    """Columns ``Delta^j x(k - delay)`` for ``j < count`` and rows ``k = first_row .. N-1``: (rows, count).

    Requires ``first_row >= delay + count - 1`` (every lag inside the record).
    Differences are taken one order at a time (never as ``x(t) - 2 x(t-1) + ...``):
    the difference of two close floats is exact, so nothing is lost to cancellation.
    Written into ``out`` when given (a Fortran-ordered block keeps each column contiguous).
    """
    n = x.size
    rows = n - first_row
    if first_row < delay + count - 1:
        raise ValueError("first_row too small for the requested lags")
    if out is None:
        out = np.empty((rows, count), order="F")
    # window[m] is Delta^j x at time first_row - delay - (count - 1) + j + m.
    window = np.asarray(x, dtype=float)[first_row - delay - (count - 1) : n - delay]
    for j in range(count):
        out[:, j] = window[count - 1 - j :]
        if j + 1 < count:
            window = np.subtract(window[1:], window[:-1])
    return out


@dataclass(frozen=True)
class Regression:
    """Delta-basis normal equations of the ARX problem for every order up to a maximum.

    ``gram`` is ``X^T X`` over the chosen rows, where column 0 of ``X`` is the
    target ``Delta y(k)``, then ``Delta^j y(k-1)`` for ``j < na_max`` at
    ``y_offset``, then per input ``i`` and candidate delay ``d`` the columns
    ``Delta^j u_i(k-d)``, ``j < nb_max``, at ``u_offset[(i, d)]``.
    """

    gram: np.ndarray
    na_max: int
    nb_max: int
    delays: tuple[int, ...]
    u_offset: dict[tuple[int, int], int]
    first_row: int

    y_offset = 1

    def __add__(self, other: Regression) -> Regression:
        """Normal equations of the union of two disjoint row ranges."""
        return Regression(
            self.gram + other.gram,
            self.na_max,
            self.nb_max,
            self.delays,
            self.u_offset,
            self.first_row,
        )


def first_row_for(na_max: int, nb_max: int, delays: Sequence[int]) -> int:
    """First sample ``k`` at which every lag of every candidate order lies inside the record."""
    return max(na_max, max(delays) + nb_max - 1, 1)


#: Rows per block when accumulating normal equations: a block of ~60 columns
#: stays in cache, so the full regressor matrix is never written to memory.
BLOCK_ROWS = 16_384


def regression_matrix(
    y: np.ndarray,
    inputs: np.ndarray,
    *,
    na_max: int,
    nb_max: int,
    delays: Sequence[int],
    rows: tuple[int, int] | None = None,
) -> tuple[np.ndarray, dict[tuple[int, int], int], int]:
    """``X`` of :class:`Regression` for samples ``rows`` (default: every ``k >= first_row``).

    Returns ``X``, the input block offsets and ``first_row``.
    """
    first = first_row_for(na_max, nb_max, delays)
    start, stop = rows if rows is not None else (first, y.size)
    start = max(start, first)
    n_inputs = inputs.shape[1]
    n_columns = 1 + na_max + n_inputs * len(delays) * nb_max
    matrix = np.empty((stop - start, n_columns), order="F")
    np.subtract(y[start:stop], y[start - 1 : stop - 1], out=matrix[:, 0])  # Delta y(k)
    differences(y[:stop], 1, na_max, start, out=matrix[:, 1 : 1 + na_max])
    offsets: dict[tuple[int, int], int] = {}
    column = 1 + na_max
    for i in range(n_inputs):
        u = inputs[:stop, i]
        for d in delays:
            offsets[(i, d)] = column
            differences(u, d, nb_max, start, out=matrix[:, column : column + nb_max])
            column += nb_max
    return matrix, offsets, first


def build_regression(
    y: np.ndarray,
    inputs: np.ndarray,
    *,
    na_max: int,
    nb_max: int,
    delays: Sequence[int],
    split: int | None = None,
    first_sample: int = 0,
) -> tuple[Regression, Regression | None]:
    """Normal equations for samples before ``split`` and (if given) from ``split`` on.

    Without ``split`` the first value covers the whole record and the second
    is None. Rows before ``first_sample`` are left out of both (their samples
    still serve as the lags of later rows: the fit of a later part of a
    record). Accumulated block by block (:data:`BLOCK_ROWS`).
    """
    delays_t = tuple(delays)
    first = max(first_row_for(na_max, nb_max, delays_t), first_sample)
    if y.size <= first + 1:
        raise ModelError(f"{y.size} samples are too few for orders up to {max(na_max, nb_max)}")

    def gram(start: int, stop: int) -> Regression:
        total: np.ndarray | None = None
        offsets: dict[tuple[int, int], int] = {}
        for block_start in range(start, stop, BLOCK_ROWS):
            block, offsets, _ = regression_matrix(
                y,
                inputs,
                na_max=na_max,
                nb_max=nb_max,
                delays=delays_t,
                rows=(block_start, min(block_start + BLOCK_ROWS, stop)),
            )
            product = block.T @ block
            total = product if total is None else total + product
        assert total is not None  # start < stop
        return Regression(total, na_max, nb_max, delays_t, offsets, first)

    if split is None:
        return gram(first, y.size), None
    cut = min(max(split, first + 1), y.size - 1)
    return gram(first, cut), gram(cut, y.size)


@dataclass(frozen=True, eq=False)  # eq=False: arrays have no single truth value
class ArxParameters:
    """A MISO ARX model: ``a`` (na + 1, ``a[0] = 1``) and per input ``b_i`` (nb_i) with delay ``nk_i``."""

    a: np.ndarray
    b: tuple[np.ndarray, ...]
    nk: tuple[int, ...]

    def stable(self) -> bool:
        return bool(max_pole_magnitude(self.a) < 1.0 - UNIT_CIRCLE_MARGIN)

    def full_numerators(self) -> list[np.ndarray]:
        """Each ``b_i`` with its delay folded in as leading zeros (``lfilter``'s ``b``)."""
        return [np.concatenate([np.zeros(d), b]) for b, d in zip(self.b, self.nk, strict=True)]


def max_pole_magnitude(den: np.ndarray) -> float:
    """Largest ``|z|`` among the roots of ``z^n A(z^-1)`` (0 for a constant denominator)."""
    den = np.trim_zeros(np.asarray(den, dtype=float), "b")
    return float(np.max(np.abs(np.roots(den)))) if den.size > 1 else 0.0


def solve_scaled(gram: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Solve ``gram @ x = rhs`` (symmetric positive semi-definite) after scaling to unit diagonal.

    ``rhs`` may be a vector or a matrix of right-hand sides. Cholesky when
    well conditioned; otherwise the minimum-norm least-squares solution of the
    scaled system, so a rank-deficient regression (an input that never
    changes, two identical channels) keeps its extra coefficients at zero
    instead of exploding.
    """
    scale = np.sqrt(np.diag(gram))
    scale[scale == 0.0] = 1.0
    scaled = gram / scale[:, None] / scale[None, :]
    column_scale = scale if rhs.ndim == 1 else scale[:, None]
    scaled_rhs = rhs / column_scale
    try:
        factor = scipy.linalg.cho_factor(scaled, check_finite=False)
        if np.linalg.cond(scaled) < 1e12:
            solution = scipy.linalg.cho_solve(factor, scaled_rhs, check_finite=False)
            return np.asarray(solution / column_scale)
    except np.linalg.LinAlgError:
        pass
    solution = np.linalg.lstsq(scaled, scaled_rhs, rcond=1e-12)[0]
    return np.asarray(solution / column_scale)


def solve_arx(
    regression: Regression, na: int, nb: Sequence[int], nk: Sequence[int]
) -> ArxParameters:
    """Least-squares ARX parameters for orders ``na``, ``nb_i``, ``nk_i`` from the normal equations.

    In the difference basis the regression is
    ``Delta y(k) = sum_j alpha_j Delta^j y(k-1) + sum_ij beta_ij Delta^j u_i(k-nk_i)``,
    so ``A(q) = 1 - q^-1 - q^-1 sum_j alpha_j (1 - q^-1)^j`` and
    ``B_i(q) = sum_j beta_ij (1 - q^-1)^j``.
    """
    if not 1 <= na <= regression.na_max:
        raise ModelError(f"na = {na} is outside the regression's 1..{regression.na_max}")
    columns = list(range(regression.y_offset, regression.y_offset + na))
    for i, (count, delay) in enumerate(zip(nb, nk, strict=True)):
        if not 1 <= count <= regression.nb_max or (i, delay) not in regression.u_offset:
            raise ModelError(f"input {i}: nb = {count}, nk = {delay} not in the regression")
        start = regression.u_offset[(i, delay)]
        columns.extend(range(start, start + count))
    index = np.asarray(columns)
    theta = solve_scaled(regression.gram[np.ix_(index, index)], regression.gram[index, 0])
    alpha = difference_matrix(na) @ theta[:na]
    a = np.concatenate([[1.0, -1.0], np.zeros(na - 1)])
    a[1:] -= alpha
    bs = []
    position = na
    for count in nb:
        bs.append(difference_matrix(count) @ theta[position : position + count])
        position += count
    return ArxParameters(a, tuple(bs), tuple(int(d) for d in nk))


def fit_arx(
    y: np.ndarray,
    inputs: np.ndarray,
    na: int,
    nb: Sequence[int],
    nk: Sequence[int],
    *,
    first_sample: int = 0,
    starts: Sequence[int] = ONE,
) -> ArxParameters:
    """MISO ARX at fixed orders over the record's rows from ``first_sample`` on (where every lag exists).

    ``inputs`` is (N, n_inputs). With several ``starts`` (stacked experiments,
    :mod:`compd.model.experiments`) the normal equations are summed over the
    experiments, each from its own first row where every lag lies inside it:
    no regressor spans two experiments (``first_sample`` must then be 0).
    Raises :class:`ModelError` with advice when the estimated denominator is
    unstable, rather than flipping poles.
    """
    y = np.asarray(y, dtype=float)
    inputs = np.asarray(inputs, dtype=float).reshape(len(y), -1)
    if len(starts) > 1 and first_sample:
        raise ModelError("a first sample and several experiments together are not supported")
    parts = [
        build_regression(
            y[part],
            inputs[part],
            na_max=na,
            nb_max=max(nb),
            delays=sorted(set(nk)),
            first_sample=first_sample,
        )[0]
        for part in spans(len(y), starts)
    ]
    regression = functools.reduce(operator.add, parts)
    parameters = solve_arx(regression, na, nb, nk)
    if not parameters.stable():
        raise ModelError(
            f"the least-squares ARX model of order na = {na} is unstable (largest pole "
            f"|z| = {max_pole_magnitude(parameters.a):.9g}): the data does not support this "
            "order. Use a lower order or --order auto; or the default fit (no --method: the "
            "lag bank or the static regression, which have no denominator to go unstable)"
        )
    return parameters


def simulate_arx(
    parameters: ArxParameters, inputs: np.ndarray, starts: Sequence[int] = ONE
) -> np.ndarray:
    """Free-run output ``sum_i B_i q^-nk_i / A u_i`` from rest (um), again at each of ``starts``.

    ``sum_i`` of the finite impulse responses first, then one recursion with
    ``1/A``: the same output as one ``lfilter(b_i, a, u_i)`` per input (what
    ``compd compare`` runs), at a fraction of the cost.
    """
    inputs = np.asarray(inputs, dtype=float)
    return each(lambda part: _simulate_arx(parameters, part), inputs, starts)


def _simulate_arx(parameters: ArxParameters, inputs: np.ndarray) -> np.ndarray:
    total = np.zeros(inputs.shape[0])
    for i, b in enumerate(parameters.full_numerators()):
        total += scipy.signal.lfilter(b, [1.0], inputs[:, i])
    response: np.ndarray = scipy.signal.lfilter([1.0], parameters.a, total)
    return response
