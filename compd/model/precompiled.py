"""Difference equations derived once, where the model is written, so the daemon only steps them.

A model file states its TFs in the forms the papers print: continuous in
``s``, or discrete in ``z^-1`` at the file's sample time. The daemon ticks at
its config's period, so a continuous TF must be discretised (zero-order
hold) and a discrete one at another rate resampled (exact d2c, then ZOH):
matrix exponentials and logarithms, scipy's ~100 MB. The modelling toolkit
does that when it writes the file and stores the result beside the TFs, one
set of difference equations per period (:class:`DifferenceEquations`); the
daemon compiles from that set with numpy alone (:func:`runnable_tf`) and
refuses a file that would need a conversion it does not carry.

Each set records the sha256 of the TFs it was derived from
(:func:`tfs_sha256`), so a TF edited after the set was written is caught
when the file is read, never run in its old form. This module imports
numpy and hashlib only; :func:`derived_tf` imports scipy through
:mod:`compd.model.transfer` when (and only when) a conversion is needed.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass

from compd.errors import ModelError
from compd.model.structure import Model
from compd.model.transfer import ContinuousTF, DiscreteTF, resample_discrete

#: Two periods closer than this (relative) are the same period: 1.0 and 0.1 * 10.
_SAME_PERIOD = 1e-9


@dataclass(frozen=True)
class DifferenceEquations:
    """Every sub-model's TF as it runs at ``period_s`` (s), keyed ``(output, sub-model name)``.

    ``tfs_sha256`` is :func:`tfs_sha256` of the model the set was derived from.
    """

    period_s: float
    tfs_sha256: str
    tfs: dict[tuple[str, str], DiscreteTF]


def same_period(a_s: float, b_s: float) -> bool:
    """True when two periods (s) are one rate up to rounding (0.1 * 10 and 1.0)."""
    return abs(a_s - b_s) <= _SAME_PERIOD * max(abs(a_s), abs(b_s))


def needs_conversion(tf: DiscreteTF | ContinuousTF, model_s: float, run_s: float) -> bool:
    """True when running ``tf`` at ``run_s`` needs scipy: continuous, or discrete at another rate."""
    return isinstance(tf, ContinuousTF) or not same_period(model_s, run_s)


def model_needs_conversion(model: Model, run_s: float) -> bool:
    """True when some sub-model of ``model`` needs a conversion to run at ``run_s``."""
    return any(
        needs_conversion(sub.tf, model.sample_time_s, run_s)
        for output in model.outputs
        for sub in output.submodels
    )


def tfs_sha256(model: Model) -> str:
    """The sha256 of what a set of difference equations is derived from: the sample time and TFs.

    Each number is written with ``repr`` (shortest round-trip) in a canonical
    JSON list, so the same TFs read from any spelling of the file give the same
    digest; gains, gates, references and positions are not part of it (they
    scale or switch a TF's output, they do not change its equation).
    """
    parts: list[object] = [repr(float(model.sample_time_s))]
    for output in model.outputs:
        for sub in output.submodels:
            tf = sub.tf
            numbers = [[repr(float(v)) for v in tf.num], [repr(float(v)) for v in tf.den]]
            if isinstance(tf, ContinuousTF):
                parts.append([output.name, sub.name, "continuous", *numbers, repr(tf.delay_s)])
            else:
                parts.append([output.name, sub.name, "discrete", *numbers, tf.nk])
    text = json.dumps(parts, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def derived_tf(tf: DiscreteTF | ContinuousTF, model_s: float, run_s: float) -> DiscreteTF:
    """``tf`` (at the model's ``model_s``) as it runs at ``run_s``: checked stable before and after.

    A discrete TF at its own rate is returned as it is (numpy alone); anything
    else is converted, which imports scipy (the modelling toolkit's side).
    """
    tf.check_stable()
    if isinstance(tf, ContinuousTF):
        discrete = tf.discretise(run_s)
    elif same_period(model_s, run_s):
        discrete = tf
    else:
        discrete = resample_discrete(tf, model_s, run_s)
    discrete.check_stable()
    return discrete


def derive(model: Model, period_s: float) -> DifferenceEquations:
    """Every sub-model's difference equation at ``period_s`` (converting: scipy where needed)."""
    tfs: dict[tuple[str, str], DiscreteTF] = {}
    for output in model.outputs:
        for index, sub in enumerate(output.submodels):
            try:
                tfs[(output.name, sub.name)] = derived_tf(sub.tf, model.sample_time_s, period_s)
            except ModelError as exc:
                where = f"outputs.{output.name}.submodels[{index}] ({sub.name})"
                raise ModelError(exc.message, where=where) from exc
    return DifferenceEquations(float(period_s), tfs_sha256(model), tfs)


def stored_at(
    equations: tuple[DifferenceEquations, ...], period_s: float
) -> DifferenceEquations | None:
    """The set written for ``period_s`` among ``equations``, or None."""
    return next((e for e in equations if same_period(e.period_s, period_s)), None)


class ConversionNeeded(ModelError):
    """The model would need scipy to run at this period and carries no equations for it."""


def runnable_tf(
    tf: DiscreteTF | ContinuousTF,
    key: tuple[str, str],
    model_s: float,
    run_s: float,
    stored: DifferenceEquations | None,
    *,
    convert: bool,
) -> DiscreteTF:
    """The difference equation the sub-model ``key`` (output, name) runs at ``run_s``.

    From ``stored`` (the file's set for this period) when there is one, else
    ``tf`` itself when it is discrete at ``run_s``; otherwise converted when
    ``convert`` (the toolkit) or refused with :class:`ConversionNeeded` (the
    daemon: numpy alone).
    """
    if stored is not None:
        stored_tf = stored.tfs[key]
        stored_tf.check_stable()
        return stored_tf
    if convert or not needs_conversion(tf, model_s, run_s):
        return derived_tf(tf, model_s, run_s)
    how = (
        "a continuous TF to discretise"
        if isinstance(tf, ContinuousTF)
        else f"a discrete TF at {model_s:g} s to resample"
    )
    raise ConversionNeeded(
        f"is {how} for the {run_s:g} s period, and the file carries no difference equations "
        f"at {run_s:g} s; compd run steps precompiled equations with numpy alone and does not "
        "convert TFs"
    )


def check_derived(model: Model, stored: DifferenceEquations, rtol: float = 1e-9) -> None:
    """Refuse ``stored`` unless each equation is what :func:`derive` gives now (to ``rtol``).

    The sha256 in the file ties a set to its TFs; this ties it to the
    conversion itself (``compd model check``: a set written by hand, or by a
    compd whose conversion was wrong, is caught before a daemon runs it).
    """
    fresh = derive(model, stored.period_s)
    for key, tf in stored.tfs.items():
        want = fresh.tfs[key]
        same = tf.nk == want.nk and all(
            len(mine) == len(theirs)
            and max((abs(m - t) for m, t in zip(mine, theirs, strict=True)), default=0.0)
            <= rtol * max(1.0, *(abs(t) for t in theirs))
            for mine, theirs in ((tf.num, want.num), (tf.den, want.den))
        )
        if not same:
            raise ModelError(
                f"its difference equation at {stored.period_s:g} s is not what its TF gives at "
                f"that period (num {list(want.num)}, den {list(want.den)}, nk {want.nk})",
                where=f"difference_equations ({key[0]}/{key[1]})",
            )
