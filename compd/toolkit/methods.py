"""Identification methods by name: one class each, one table, as Klipper's ``getchoice``.

``compd fit --method NAME`` and ``compd extend --method NAME`` look the name up
in :data:`METHODS` (:func:`method_named`); nothing else compares method names.
Every method is judged by the same folds (:mod:`compd.toolkit.nestedselect`,
beside the static regression, always scored); each class says which
candidates it has scored, which structures it takes (phase gate, position,
denoising), where its guard rails refuse it, how it identifies the prepared
data, and what it adds to the model file's notes.

A new method is one class here and one line in :data:`METHODS`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from compd.model.identify import Identification, identify
from compd.model.lagbank import LagBankFit
from compd.model.orderfit import Progress
from compd.toolkit.candidates import describe_lag_bank, lag_bank_identification
from compd.toolkit.nestedselect import BASELINE, LAG_BANK, Selection


@dataclass(frozen=True, eq=False)
class Prepared:
    """What every method fits on: the output and each input as changes, with their structure.

    ``changes``: each input (its unit) as the change from its first value at
    each experiment's start (``starts``); ``gate``: open where the phase-gate
    column is positive; ``position``: the axis position minus its reference (mm).
    Samples before ``first_sample`` are run through, never fitted (``--from``).
    """

    y: np.ndarray
    changes: Mapping[str, np.ndarray]
    sample_time_s: float
    order: int | str = "auto"
    gate: np.ndarray | None = None
    position: np.ndarray | None = None
    first_sample: int = 0
    starts: tuple[int, ...] = (0,)
    progress: Progress | None = None


class FitMethod:
    """One identification method: what it is scored with, what it takes, how it identifies."""

    name: ClassVar[str]
    #: How a refusal names it.
    title: ClassVar[str]
    #: The regularised lag bank is scored by the folds beside the regression (no structure).
    scores_lag_bank: ClassVar[bool] = False
    #: Takes ``--phase-gate``, ``--position`` and ``--denoise``.
    takes_structure: ClassVar[bool] = True
    #: ``compd fit`` over several files refuses it (it searches one record).
    one_record: ClassVar[bool] = False
    #: ``compd extend --method`` takes it (a static regression adds no dynamics to a residue).
    extends: ClassVar[bool] = True
    #: ``compd extend`` over several experiments refuses it (it identifies one record).
    extends_one_record: ClassVar[bool] = False
    #: Its channels are the lags of a bank: one sub-model per input and time constant.
    lags: ClassVar[bool] = False
    #: Refused when it holds worse than the regression on held-out folds (unless forced).
    judged_against_regression: ClassVar[bool] = True

    def candidates(self, structured: bool) -> tuple[str, ...]:
        """The candidates the folds score for it (the regression always, as the baseline)."""
        return (LAG_BANK, BASELINE) if self.scores_lag_bank and not structured else (BASELINE,)

    def kept(self, selection: Selection, structured: bool) -> FitMethod:
        """The method whose model is written once ``selection`` has scored the candidates."""
        return self

    def for_extension(self) -> tuple[FitMethod, FitMethod | None]:
        """The method a new sub-model is identified by, and the one tried if it fails the rails."""
        return self, None

    def identify(self, prepared: Prepared, lag_bank: LagBankFit | None) -> Identification:
        """Identify ``prepared`` (``lag_bank``: the one the folds fitted, when scored)."""
        return identify(
            prepared.y,
            dict(prepared.changes),
            sample_time_s=prepared.sample_time_s,
            method=self.name,  # type: ignore[arg-type]  # the table's names are identify's
            order="auto" if prepared.order == "auto" else int(prepared.order),
            gate=prepared.gate,
            position=prepared.position,
            progress=prepared.progress,
            first_sample=prepared.first_sample,
            starts=prepared.starts,
        )

    def notes(self, selection: Selection) -> str | None:
        """What it adds to the model file's provenance notes, if anything."""
        return None


class LagBank(FitMethod):
    """The regression plus first-order lags shrunk toward it (:mod:`compd.model.lagbank`)."""

    name = LAG_BANK
    title = "the lag bank"
    scores_lag_bank = True
    takes_structure = False
    lags = True

    def identify(self, prepared: Prepared, lag_bank: LagBankFit | None) -> Identification:
        assert lag_bank is not None  # scored by the folds before it is written
        return lag_bank_identification(lag_bank, list(prepared.changes), prepared.sample_time_s)

    def notes(self, selection: Selection) -> str | None:
        return None if selection.lag_bank is None else describe_lag_bank(selection.lag_bank)


class Regression(FitMethod):
    """The controllers' static multiple linear regression (the baseline every fit is printed beside)."""

    name = BASELINE
    title = "the static regression"
    extends = False


class OutputError(FitMethod):
    """Output-error TFs, orders searched on held-back data (:mod:`compd.model.oe`)."""

    name = "oe"
    title = "the output-error model"
    one_record = True
    extends_one_record = True


class ARX(FitMethod):
    """ARX by least squares (:mod:`compd.model.arx`); over several files at a given order."""

    name = "arx"
    title = "the ARX model"
    extends_one_record = True


class Auto(FitMethod):
    """The default: whichever of the lag bank and the regression holds better on held-out folds.

    With a phase gate, a position or denoising it is ``oe`` (the lag bank has
    none of them); ``compd extend``'s auto is ``oe``, or the lag bank when the
    OE sub-model fails the guard rails.
    """

    name = "auto"
    title = "the default"
    scores_lag_bank = True
    judged_against_regression = False  # it chose by these figures already

    def kept(self, selection: Selection, structured: bool) -> FitMethod:
        return method_named(OutputError.name if structured else selection.kept)

    def for_extension(self) -> tuple[FitMethod, FitMethod | None]:
        return method_named(OutputError.name), method_named(LagBank.name)

    def identify(self, prepared: Prepared, lag_bank: LagBankFit | None) -> Identification:
        raise AssertionError("auto identifies by the method it keeps")  # pragma: no cover


#: Every method by the name ``--method`` takes; the first is the default.
METHODS: dict[str, type[FitMethod]] = {
    Auto.name: Auto,
    LagBank.name: LagBank,
    OutputError.name: OutputError,
    ARX.name: ARX,
    Regression.name: Regression,
}


def method_named(name: str) -> FitMethod:
    """The method called ``name``; ``KeyError`` for another (the option checks name the choices)."""
    return METHODS[name]()


#: What ``compd fit --method`` accepts, the default first.
FIT_METHODS = tuple(METHODS)
#: What ``compd extend --method`` accepts, the default first.
EXTEND_METHODS = tuple(name for name, method in METHODS.items() if method.extends)


def writes_lags(identified_by: str) -> bool:
    """Whether a model identified by the method so named is a bank of lags (one sub-model per lag)."""
    method = METHODS.get(identified_by)
    return method is not None and method.lags
