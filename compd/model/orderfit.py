"""ARX and OE fits for :func:`compd.model.identify.identify`: at a fixed order, or the order held-back data chooses.

``order=N``: one fit of order ``N`` on the fitted samples (``na = nb_i = N``
for ARX, ``nf_i = nb_i = N`` for OE, ``nk_i = 1``). ``order="auto"``: ARX by
:func:`compd.model.orders.search_arx`, then refitted on the whole record; OE
by its own free-run fit on the held-back last third, orders 1, 2, 3 until one
buys nothing (:data:`~compd.model.orders.TOLERANCE_POINTS`), then refitted
on the whole record. Every OE fit starts from ARX refined by
Steiglitz-McBride. Progress is reported per stage (one bar each).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from compd.errors import ModelError
from compd.model.arx import ArxParameters, fit_arx, solve_arx
from compd.model.experiments import ONE
from compd.model.metrics import fit_percent
from compd.model.oe import OeParameters, fit_oe, oe_from_arx, simulate_oe, steiglitz_mcbride
from compd.model.orders import (
    TOLERANCE_POINTS,
    TOLERANCE_RELATIVE,
    choose,
    search_arx,
    split_index,
)

#: Called with a stage name ("ARX order search", "OE order 2", ...) and the fraction of
#: that stage done (0..1); a new name starts a new stage (one progress bar each).
Progress = Callable[[str, float], None]
#: Largest order tried by ``order="auto"`` (and accepted as a fixed order).
MAX_ORDER = 3
#: Iteration budget of each OE candidate in the automatic order search (the
#: chosen one is refined to convergence on the whole record afterwards).
CANDIDATE_ITERATIONS = 25
#: Fewest samples an identification accepts: a few per parameter is not enough to validate.
MIN_SAMPLES = 50


@dataclass(frozen=True)
class Orders:
    """Orders per channel: ``nb`` numerator taps, ``nf`` denominator order, ``nk`` delay (samples).

    For ARX every ``nf_i`` is ``na``, the shared denominator's order; for MLR
    every order is 0 (static gains).
    """

    na: int
    nb: tuple[int, ...]
    nf: tuple[int, ...]
    nk: tuple[int, ...]


def fit_arx_order(
    y: np.ndarray,
    u: np.ndarray,
    order: int | Literal["auto"],
    report: Progress,
    first: int,
    starts: Sequence[int] = ONE,
) -> tuple[ArxParameters, Orders, float | None]:
    """ARX on channels ``u`` (columns), its orders, and the held-back fit % when chosen.

    Over several stacked experiments (``starts``) only at a given order: the
    held-back last third of the order search would be part of one experiment.
    """
    n_channels = u.shape[1]
    if order != "auto":
        n = int(order)
        report(f"ARX least squares, order {n}", 0.0)
        arx = fit_arx(
            y, u, n, [n] * n_channels, [1] * n_channels, first_sample=first, starts=starts
        )
        report(f"ARX least squares, order {n}", 1.0)
        return arx, Orders(n, (n,) * n_channels, (n,) * n_channels, (1,) * n_channels), None
    if len(starts) > 1:
        raise ModelError(
            "ARX orders are chosen on the held-back last third of one record, not over several "
            "experiments: give the order (--order 1, 2 or 3)"
        )
    search = search_arx(
        y, u, na_max=MAX_ORDER, nb_max=MAX_ORDER, progress=report, first_sample=first
    )
    best = search.best
    if best.parameters is None:
        raise ModelError(
            "every ARX order up to 3 gave an unstable model on this data: it does not show "
            "how the output responds to the inputs through one shared denominator (slow drift, "
            "inputs that move together). Fit without --method: the lag bank or the static "
            "regression need no stable denominator"
        )
    assert search.validation is not None  # search_arx always holds data back
    # The whole record: the sum of both parts' normal equations.
    arx = solve_arx(search.estimation + search.validation, best.na, best.nb, best.nk)
    if not arx.stable():
        arx = best.parameters  # the estimation-part model is stable; keep it rather than flip poles
    orders = Orders(best.na, best.nb, (best.na,) * n_channels, best.nk)
    return arx, orders, best.validation_fit_percent


def _oe_run(
    y: np.ndarray,
    u: np.ndarray,
    n: int,
    nk: tuple[int, ...],
    report: Progress,
    stage: str,
    max_iterations: int = 50,
    first: int = 0,
) -> OeParameters:
    """ARX of order ``n``, refined by Steiglitz-McBride, then the output-error fit."""
    n_channels = u.shape[1]
    report(stage, 0.0)
    try:
        arx = fit_arx(y, u, n, [n] * n_channels, list(nk), first_sample=first)
    except ModelError:
        if n == 1:
            raise
        # A noisy record can make the higher-order ARX start unstable: repeat
        # the order-1 pole instead, a valid (if crude) start that OE refines.
        crude = fit_arx(y, u, 1, [n] * n_channels, list(nk), first_sample=first)
        a = np.poly(np.repeat(np.roots(crude.a), n))
        arx = ArxParameters(a, crude.b, crude.nk)
    report(stage, 0.05)
    start = steiglitz_mcbride(y, u, arx, first_sample=first)
    report(stage, 0.2)
    initial = oe_from_arx(start.a, start.b, start.nk, [n] * n_channels)

    def on_iteration(iteration: int, fraction: float, cost: float) -> None:
        report(stage, 0.2 + 0.8 * fraction)

    result = fit_oe(
        y, u, initial, max_iterations=max_iterations, progress=on_iteration, first_sample=first
    ).parameters
    report(stage, 1.0)
    return result


def fit_oe_order(
    y: np.ndarray, u: np.ndarray, order: int | Literal["auto"], report: Progress, first: int
) -> tuple[OeParameters, Orders, float | None]:
    """OE on channels ``u`` (columns), its orders, and the held-back fit % when chosen."""
    n_channels = u.shape[1]
    if order != "auto":
        n = int(order)
        params = _oe_run(y, u, n, (1,) * n_channels, report, f"OE order {n}", first=first)
        return params, Orders(0, (n,) * n_channels, (n,) * n_channels, (1,) * n_channels), None
    # The common order by OE's own validation fit, stopping once an order buys
    # nothing. Delays stay at the ZOH sample (nk = 1): ARX's delay search
    # (0..2 samples) is immaterial next to time constants of minutes, and its
    # choice is biased by output noise like its poles.
    nk = (1,) * n_channels
    split = first + split_index(y.size - first)
    candidates: list[_OeCandidate] = []
    reasons: list[str] = []
    for n in range(1, MAX_ORDER + 1):
        stage = f"OE order {n} (first two thirds)"
        try:
            params = _oe_run(
                y[:split], u[:split], n, nk, report, stage, CANDIDATE_ITERATIONS, first
            )
        except ModelError as exc:
            reasons.append(f"order {n}, {exc.message}")
            report(stage, 1.0)
            continue
        score = fit_percent(y[split:], simulate_oe(params, u)[split:])
        candidate = _OeCandidate(n, params, score)
        if candidates and candidate.usable:
            best_error = min(c.error for c in candidates if c.usable)
            if candidate.error > best_error - TOLERANCE_POINTS - TOLERANCE_RELATIVE * best_error:
                candidates.append(candidate)
                break
        candidates.append(candidate)
    if not candidates:
        raise ModelError(
            "no output-error model of order 1..3 could be fitted to this data (at "
            + reasons[0].split(". ")[0]
            + "): the output does not follow these inputs through stable poles of their own "
            "(slow drift, inputs that move together). Fit without --method: the lag bank or the "
            "static regression need no poles of their own; or give OE fewer inputs"
        )
    best = choose(candidates)
    n = best.order
    stage = f"OE order {n}, whole record"
    report(stage, 0.0)

    def on_iteration(iteration: int, fraction: float, cost: float) -> None:
        report(stage, fraction)

    whole = fit_oe(y, u, best.parameters, progress=on_iteration, first_sample=first).parameters
    report(stage, 1.0)
    orders = Orders(0, (n,) * n_channels, (n,) * n_channels, nk)
    return whole, orders, best.validation_fit_percent


@dataclass(frozen=True)
class _OeCandidate:
    """An OE fit of one common order on the estimation part, scored on the held-back part."""

    order: int
    parameters: OeParameters
    validation_fit_percent: float

    @property
    def size(self) -> int:
        return sum(
            b.size + f.size - 1 for b, f in zip(self.parameters.b, self.parameters.f, strict=True)
        )

    @property
    def error(self) -> float:
        return 100.0 - self.validation_fit_percent

    @property
    def usable(self) -> bool:
        return bool(np.isfinite(self.validation_fit_percent))
