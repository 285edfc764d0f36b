"""The model file's ``difference_equations``: each sub-model's TF as it runs at a period, precompiled.

An optional, additive section of ``compd.model/1`` (files without it load as
before)::

    difference_equations:
      - period_s: 1.0
        tfs_sha256: "3f2a..."          # of the sample time and TFs they were derived from
        outputs:
          "disp_z_um":
            "T_spindle_degC": {nk: 1, num: [...], den: [...]}   # ascending powers of z^-1

The toolkit derives them (:func:`compd.model.precompiled.derive`: zero-order
hold, exact resampling; scipy) when it writes a model file
(:func:`derived_sets` for the periods of :data:`RUN_PERIODS_S`, written by
:func:`compd.files.modelwriter.equations_lines`) and
``compd model compile`` adds a period to a file as it stands
(:func:`with_equations`, the rest of the text kept). Reading a file checks
each set against the file's TFs (:func:`equation_sets`): a TF edited after
its equations were written is refused, never run in its old form.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field

from compd.errors import ModelError, ModelFileError
from compd.model.limits import MAX_DELAY_SAMPLES, MAX_ORDER, MAX_SAMPLE_TIME_S
from compd.model.precompiled import (
    DifferenceEquations,
    derive,
    model_needs_conversion,
    same_period,
    tfs_sha256,
)
from compd.model.structure import Model
from compd.model.transfer import DiscreteTF

#: The periods (s) a written model file carries equations for, beside its own sample time:
#: the config's default ``period_s``, which every bundled config ticks at.
RUN_PERIODS_S = (1.0,)
#: At most this many periods in one file.
MAX_PERIODS = 16
_FiniteFloat = Annotated[float, Field(allow_inf_nan=False)]


class _Strict(BaseModel):
    # Patterns matched by Python's re (written with \Z, which ends a value as Rust's $ does):
    # each Rust regex pydantic compiles costs the daemon 0.1-0.3 MB. Schemas built when first
    # used: a section's own validator only where it is validated alone.
    model_config = ConfigDict(
        extra="forbid", frozen=True, strict=False, regex_engine="python-re", defer_build=True
    )


class EquationDoc(_Strict):
    """One sub-model's difference equation: ascending powers of ``z^-1``, input delay ``nk`` samples."""

    num: list[_FiniteFloat] = Field(min_length=1, max_length=MAX_ORDER + 1)
    den: list[_FiniteFloat] = Field(min_length=1, max_length=MAX_ORDER + 1)
    nk: int = Field(default=0, ge=0, le=MAX_DELAY_SAMPLES)


class DifferenceEquationsDoc(_Strict):
    """Every sub-model's TF at one run period, derived by compd; ``compd run`` steps these as they are."""

    #: The loop period (s) these equations run at (a config's ``period_s``).
    period_s: _FiniteFloat = Field(gt=0, le=MAX_SAMPLE_TIME_S)
    #: The sha256 of the sample time and TFs they were derived from (compd.model.precompiled).
    tfs_sha256: str = Field(pattern=r"^[0-9a-f]{64}\Z")
    #: Per output, per sub-model name: its difference equation at ``period_s``.
    outputs: dict[str, dict[str, EquationDoc]]


def equation_sets(
    docs: Sequence[DifferenceEquationsDoc] | None,
    model: Model,
    path: str | Path,
    place: Callable[[tuple[str | int, ...]], str] = lambda at: ".".join(map(str, at)),
) -> tuple[DifferenceEquations, ...]:
    """The file's sets, each checked against ``model`` (its TFs, its sub-models).

    A refusal names the place as ``place`` spells a key path (the file's line, where known).
    """
    sets: list[DifferenceEquations] = []
    compile_fix = (
        f"Write them anew from the TFs with 'compd model compile {path}' (or delete the "
        "'difference_equations' section)"
    )
    expected = {o.name: [s.name for s in o.submodels] for o in model.outputs}
    digest = tfs_sha256(model)
    for index, doc in enumerate(docs or ()):
        at: tuple[str | int, ...] = ("difference_equations", index)
        if any(same_period(doc.period_s, s.period_s) for s in sets):
            raise ModelFileError(
                path,
                f"a second set at {doc.period_s:g} s",
                where=place((*at, "period_s")),
                fix="Keep one set per period",
            )
        if doc.tfs_sha256 != digest:
            raise ModelFileError(
                path,
                "these equations were derived from other TFs (a sub-model's tf or the sample time "
                "changed after they were written), so they are not this model's",
                where=place((*at, "tfs_sha256")),
                fix=compile_fix,
            )
        found = {name: list(subs) for name, subs in doc.outputs.items()}
        if found != expected:
            raise ModelFileError(
                path,
                f"names the sub-models {found}, but the model's are {expected}",
                where=place((*at, "outputs")),
                fix=compile_fix,
            )
        tfs: dict[tuple[str, str], DiscreteTF] = {}
        for output, subs in doc.outputs.items():
            for name, equation in subs.items():
                try:
                    tfs[(output, name)] = DiscreteTF.from_coefficients(
                        equation.num, equation.den, equation.nk
                    )
                except ModelError as exc:
                    where = place((*at, "outputs", output, name))
                    raise ModelFileError(path, exc.message, where=where, fix=compile_fix) from exc
        sets.append(DifferenceEquations(doc.period_s, digest, tfs))
    return tuple(sets)


def kept_periods(parent: Sequence[DifferenceEquationsDoc] | None) -> tuple[float, ...]:
    """:data:`RUN_PERIODS_S` and the periods a parent file carried: a derived file runs where it did."""
    return (*RUN_PERIODS_S, *(doc.period_s for doc in parent or ()))


def derived_sets(model: Model, periods_s: Iterable[float]) -> list[DifferenceEquations]:
    """The sets a written file carries: each period of ``periods_s`` and the model's own, where needed.

    A period the model runs at without converting (its discrete TFs at their
    own rate) needs none; one it cannot be brought to (a pole with no
    continuous equivalent) is left out, and the daemon refuses that period
    naming the fix, whose ``compd model compile`` then says why.
    """
    sets: list[DifferenceEquations] = []
    for period_s in sorted({float(model.sample_time_s), *(float(p) for p in periods_s)}):
        if any(same_period(period_s, s.period_s) for s in sets):
            continue
        if not model_needs_conversion(model, period_s):
            continue
        try:
            sets.append(derive(model, period_s))
        except ModelError:
            continue
    return sets[:MAX_PERIODS]


_TOP_KEY = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*:")
_SECTION = "difference_equations:"


def with_equations(text: str, block: list[str]) -> str:
    """``text`` (a model file) with its ``difference_equations`` block replaced by ``block``.

    Everything else is kept as written, comments included. The block goes
    where it stood, else right after ``outputs`` (before the comment lines
    that lead the next top-level key), else at the end.
    """
    lines = text.splitlines()
    starts = [i for i, line in enumerate(lines) if _TOP_KEY.match(line)]
    old = next((i for i in starts if lines[i].startswith(_SECTION)), None)
    if old is not None:
        begin = _leading_comments(lines, old)
        end = _leading_comments(lines, next((i for i in starts if i > old), len(lines)))
        del lines[begin:end]
        at = begin
    else:
        outputs = next((i for i in starts if lines[i].startswith("outputs:")), None)
        following = [i for i in starts if outputs is not None and i > outputs]
        at = _leading_comments(lines, following[0]) if following else len(lines)
    lines[at:at] = block
    return "\n".join(lines) + "\n"


def _leading_comments(lines: list[str], index: int) -> int:
    """The first of the comment lines right above ``lines[index]`` (``index`` if none)."""
    while index > 0 and lines[index - 1].startswith("#"):
        index -= 1
    return index
