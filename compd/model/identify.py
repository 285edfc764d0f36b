"""Identification: transfer functions from logged inputs to a measured displacement.

The public entry point is :func:`identify`; the ARX and OE fits at a fixed
or automatically chosen order are :mod:`compd.model.orderfit`. Three methods:

``mlr``
    The static multiple linear regression CNC controllers ship (Horejs 2010
    eq. 1, Pahk 2002 eq. 1): ``y(k) = sum_i k_i u_i(k)`` by least squares. No
    intercept: inputs and output are changes from the start of the record,
    so a model that starts at zero needs none (and ``compd compare`` starts
    every model at zero). The baseline to beat.
``arx``
    MISO ARX with one common denominator (Horejs 2015 eq. 1, Pahk 2002 eq. 4),
    :mod:`compd.model.arx`; orders and delays chosen on held-back data by
    free-run simulation fit (:mod:`compd.model.orders`) unless given.
``oe``
    MISO output-error, one denominator per input (:mod:`compd.model.oe`),
    started from ARX refined by Steiglitz-McBride and fitted on the free-run
    simulation error, because the daemon runs the model in simulation. With
    ``order="auto"`` the common order ``nf_i = nb_i = n`` is chosen by OE's
    own fit on held-back data (orders 1, 2, 3 until one buys nothing), with
    ``nk_i = 1``, then refitted on the whole record.

Phase gate (Post-process 2024 eq. 5): with ``gate`` (True while the spindle turns),
every input ``u_i`` gets two channels: the cooling channel on ``u_i`` (always
on) and the heating-difference channel on ``g(k) u_i(k)``. Post-process 2024 switches
the heating-difference TF's *output* with ``g_n``; compd switches its
*input* instead: the regression stays linear in the parameters (an output
gate multiplies a filtered signal by ``g``, which ARX cannot express), and
when the spindle stops the extra heating contribution decays with the TF's
own time constants instead of dropping to zero in one sample, which a steel
structure cannot do. The model file records it as ``applies_to: input``.

Position (Pahk 2002 eq. 5): with ``position`` (``P - P_ref``, mm), every
input gets an offset channel on ``u_i`` and a slope channel whose TF output is
multiplied by the position; see :mod:`compd.model.position` for how they are
fitted (as input channels ``u_i * P``, then numerators refitted with ``P``
after the TF).

Every fit reported is the Horejs 2015 eq. 2 fit of the free-run simulation from
rest (inputs as changes from start, as ``compd compare`` runs the model), never
a one-step prediction.

A later part of a record (``first_sample``): every method runs its model
from rest at sample 0 and counts only the samples from ``first_sample`` on,
in its loss and in every fit it reports: MLR regresses those rows; ARX's
equation error takes those rows (earlier samples serve as their lags); OE,
Steiglitz-McBride and the position refinement filter from sample 0 and sum
the simulation error over those rows; the held-back third for the order
choice is the last third of those rows. So a fit on hours 10..32 of a log
holds the model's state and the inputs' references of the whole log.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import scipy.signal

from compd.errors import ModelError
from compd.model.arx import simulate_arx
from compd.model.experiments import ONE, spans
from compd.model.metrics import fit_percent
from compd.model.orderfit import MAX_ORDER, Orders, Progress, fit_arx_order, fit_oe_order
from compd.model.position import (
    channel_scales,
    check_position,
    refine_scaled,
    refit_numerators,
    simulate_scaled,
)
from compd.model.transfer import DiscreteTF

Method = Literal["arx", "oe", "mlr", "lagbank"]
#: The methods :func:`identify` runs; ``lagbank`` is :mod:`compd.model.lagbank`'s (it needs folds).
METHODS: tuple[Method, ...] = ("arx", "oe", "mlr")
#: Fewest samples an identification accepts: a few per parameter is not enough to validate.
MIN_SAMPLES = 50


@dataclass(frozen=True)
class IdentifiedTF:
    """One channel's TF, ``B(z^-1) / A(z^-1)`` with delay ``nk`` in ascending powers of ``z^-1``."""

    input_name: str
    tf: DiscreteTF
    gated: bool  # True for the heating-difference channel of a phase gate
    sloped: bool = False  # True for a slope channel (Pahk 2002 m1): output times the position
    time_constant_s: float | None = None  # a lag-bank channel's fixed time constant (0: a gain)


@dataclass(frozen=True, eq=False)
class Identification:
    """An identified model: one TF per channel, and how well it simulates the data (fit %, Horejs 2015 eq. 2)."""

    method: Method
    channels: tuple[IdentifiedTF, ...]
    sample_time_s: float
    fit_percent: float  # free-run simulation fit on the whole record it was fitted on
    validation_fit_percent: float | None  # on the held-back part when orders were chosen
    orders: Orders
    simulated_um: np.ndarray = field(repr=False)  # the free-run output over the record


def _channels(
    inputs: Mapping[str, np.ndarray],
    gate: np.ndarray | None,
    n: int,
    position: np.ndarray | None = None,
) -> tuple[list[tuple[str, bool, bool]], np.ndarray]:
    """Channels ``(name, gated, sloped)`` and an (n, n_channels) Fortran-ordered array.

    A gated channel is ``u_i * gate``, a slope channel ``u_i * position``
    (step 1 of :mod:`compd.model.position`); each channel is contiguous.
    """
    if not inputs:
        raise ModelError("no inputs given: name at least one input signal")
    names: list[tuple[str, bool, bool]] = []
    for name in inputs:
        names.append((name, False, False))
        if gate is not None:
            names.append((name, True, False))
        if position is not None:
            names.append((name, False, True))
    u = np.empty((n, len(names)), order="F")
    column = 0
    for name, values in inputs.items():
        values = np.asarray(values, dtype=float)
        if values.shape != (n,):
            raise ModelError(f"input {name!r} has shape {values.shape}, the output has ({n},)")
        low, high = values.min(), values.max()  # NaN or inf shows in one of them
        if not (np.isfinite(low) and np.isfinite(high)):
            raise ModelError(f"input {name!r} contains NaN or inf")
        if low == high:
            raise ModelError(
                f"input {name!r} never changes, so its effect cannot be identified; "
                "leave it out or use data in which it varies"
            )
        u[:, column] = values
        column += 1
        for scale in (gate, position):
            if scale is not None:
                np.multiply(values, scale, out=u[:, column])
                column += 1
    return names, u


def _check_gate(gate: np.ndarray | None, n: int) -> np.ndarray | None:
    if gate is None:
        return None
    g = np.asarray(gate)
    if g.shape != (n,):
        raise ModelError(f"gate has shape {g.shape}, the output has ({n},)")
    g = g.astype(bool)
    if g.all() or not g.any():
        state = "always" if g.all() else "never"
        raise ModelError(
            f"the phase-gate signal is {state} > 0 in this record, so heating and cooling "
            "cannot be told apart; use data with both phases or drop the phase gate"
        )
    return g.astype(float)


#: What an estimator returns: the channels' TFs, their orders, the held-back fit % when the
#: order was searched (else None), and the output simulated over the record (um).
Estimate = tuple[list[DiscreteTF], Orders, float | None, np.ndarray]
#: An estimator: (y, u, order, progress, first sample, experiment starts) -> its estimate.
Estimator = Callable[
    [np.ndarray, np.ndarray, int | Literal["auto"], Progress, int, Sequence[int]], Estimate
]


def _mlr(
    y: np.ndarray,
    u: np.ndarray,
    order: int | Literal["auto"],
    report: Progress,
    first_sample: int,
    starts: Sequence[int],
) -> Estimate:
    """Static gains by least squares: y = u k."""
    gains = np.linalg.lstsq(u[first_sample:], y[first_sample:], rcond=None)[0]
    tfs = [DiscreteTF.from_coefficients([k], [1.0], 0) for k in gains]
    n = len(tfs)
    return tfs, Orders(0, (1,) * n, (0,) * n, (0,) * n), None, u @ gains


def _arx(
    y: np.ndarray,
    u: np.ndarray,
    order: int | Literal["auto"],
    report: Progress,
    first_sample: int,
    starts: Sequence[int],
) -> Estimate:
    """ARX by least squares, one shared denominator (:mod:`compd.model.arx`)."""
    arx, orders, validation = fit_arx_order(y, u, order, report, first_sample, starts)
    tfs = [DiscreteTF.from_coefficients(b, arx.a, nk) for b, nk in zip(arx.b, arx.nk, strict=True)]
    # One recursion for the shared denominator: the same output as one
    # lfilter per channel (what compare runs) to rounding, in half the time.
    return tfs, orders, validation, simulate_arx(arx, u, starts)


def _oe(
    y: np.ndarray,
    u: np.ndarray,
    order: int | Literal["auto"],
    report: Progress,
    first_sample: int,
    starts: Sequence[int],
) -> Estimate:
    """Output-error TFs, one record (:mod:`compd.model.oe`)."""
    oe, orders, validation = fit_oe_order(y, u, order, report, first_sample)
    tfs = [
        DiscreteTF.from_coefficients(b, f, nk) for b, f, nk in zip(oe.b, oe.f, oe.nk, strict=True)
    ]
    return tfs, orders, validation, simulate_channels(tfs, u)


#: Each method of :data:`METHODS` by name: its estimator.
ESTIMATORS: dict[str, Estimator] = {"arx": _arx, "oe": _oe, "mlr": _mlr}
#: The methods that fit one record only (not several experiments stacked).
ONE_RECORD = frozenset({"oe"})


def identify(
    y: np.ndarray,
    inputs: Mapping[str, np.ndarray],
    *,
    sample_time_s: float,
    method: Method = "oe",
    order: int | Literal["auto"] = "auto",
    gate: np.ndarray | None = None,
    position: np.ndarray | None = None,
    progress: Progress | None = None,
    first_sample: int = 0,
    starts: Sequence[int] = ONE,
) -> Identification:
    """Identify TFs from ``inputs`` (changes from start) to ``y`` (um), sampled every ``sample_time_s``.

    ``order``: ``"auto"`` (chosen on held-back data) or ``N`` in 1..3
    (``na = nb_i = N``, ``nk_i = 1`` for ARX; ``nf_i = nb_i = N``, ``nk_i = 1`` for
    OE; ignored by MLR). ``gate``: True while the phase-gate signal is > 0.
    ``position``: ``P - P_ref`` in mm (Pahk 2002 slope channels), at two or
    more distinct values; not together with ``gate``. ``first_sample``: the
    first sample fitted and scored (see the module docstring); the model
    still runs from rest at sample 0. ``starts``: the first sample of each
    stacked experiment (:mod:`compd.model.experiments`), where the model
    restarts from rest and no ARX regressor reaches back across; ``mlr`` and
    ``arx`` at a given order only.
    Raises :class:`ModelError` on bad arguments and on a fixed-order fit that
    is unstable.
    """
    y = np.asarray(y, dtype=float)
    if y.ndim != 1 or not 0 <= first_sample <= y.size - MIN_SAMPLES:
        raise ModelError(
            f"the output needs at least {MIN_SAMPLES} samples to fit, got "
            f"{y.size - first_sample if y.ndim == 1 else y.shape}"
        )
    if not np.all(np.isfinite(y)):
        raise ModelError("the output contains NaN or inf")
    if not (np.isfinite(sample_time_s) and sample_time_s > 0):
        raise ModelError(f"sample time must be > 0 s, got {sample_time_s}")
    if method not in METHODS:
        raise ModelError(f"unknown method {method!r}; use one of {', '.join(METHODS)}")
    if order != "auto" and (
        isinstance(order, bool) or int(order) != order or not 1 <= int(order) <= MAX_ORDER
    ):
        raise ModelError(f"order must be 'auto' or a whole number 1..{MAX_ORDER}, got {order!r}")
    if gate is not None and position is not None:
        raise ModelError(
            "a phase gate and a position together are not supported; fit the axis with one"
        )
    several = len(spans(y.size, starts)) > 1
    if several and (method in ONE_RECORD or gate is not None or position is not None):
        raise ModelError(
            "several experiments are fitted by mlr, arx (at a given order) or the lag bank; "
            "OE, a phase gate and a position need one record"
        )
    scale = None if position is None else check_position(position, y.size)
    names, u = _channels(inputs, _check_gate(gate, y.size), y.size, scale)

    def report(message: str, fraction: float) -> None:
        if progress is not None:
            progress(message, fraction)

    tfs, orders, validation, simulated = ESTIMATORS[method](
        y, u, order, report, first_sample, starts
    )
    if scale is not None:
        sloped = [slope for _, _, slope in names]
        unscaled = np.column_stack([np.asarray(inputs[name], dtype=float) for name, _, _ in names])
        scales = channel_scales(sloped, scale)
        refitted = refit_numerators(y, unscaled, tfs, scales, first_sample=first_sample)
        tfs = refine_scaled(y, unscaled, refitted, scales, first_sample=first_sample)
        simulated = simulate_scaled(tfs, unscaled, scales)
    return Identification(
        method=method,
        channels=tuple(
            IdentifiedTF(name, tf, gated, sloped)
            for (name, gated, sloped), tf in zip(names, tfs, strict=True)
        ),
        sample_time_s=float(sample_time_s),
        fit_percent=fit_percent(y[first_sample:], simulated[first_sample:]),
        validation_fit_percent=validation,
        orders=orders,
        simulated_um=simulated,
    )


def simulate_channels(tfs: list[DiscreteTF], inputs: np.ndarray) -> np.ndarray:
    """``sum_i TF_i(u_i)`` from rest: one ``lfilter`` per channel, exactly as ``compd compare`` runs it."""
    total = np.zeros(inputs.shape[0])
    for i, tf in enumerate(tfs):
        total += scipy.signal.lfilter(tf.b, tf.a, inputs[:, i])
    return total
