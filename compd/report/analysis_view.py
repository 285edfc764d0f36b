"""What the report reads from ``compd.analysis`` results, in one place.

Failing windows and the candidate ranking are computed by ``compd.analysis``
(the same functions ``compd compare`` and ``compd diagnose`` call, so all
three say the same thing); the report only shows them. A diagnosis may be
missing with a reason (a record too short to cross-validate, no candidate
signal): then the reason is shown instead.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from compd.analysis import DiagnosisResult, WindowsResult
from compd.model.windows import FailingWindow


@dataclass(frozen=True)
class CandidateRow:
    """One candidate signal as the report shows it."""

    signal: str
    effect: str
    explained_percent: float
    time_constant_s: float
    gain_um_per_unit: float
    sign: int
    lag_s: float
    xcorr_peak: float
    xcorr_bound: float
    significant: bool


def windows(result: WindowsResult) -> Sequence[FailingWindow]:
    """The failing windows, in time order."""
    return result.windows


def tolerance_um(result: WindowsResult) -> float:
    """The residue RMS above which a window fails, in um."""
    return result.tolerance_um


def candidates(result: DiagnosisResult | str) -> list[CandidateRow]:
    """Candidates best first; none when the diagnosis could not be made."""
    if isinstance(result, str):
        return []
    return [
        CandidateRow(
            signal=c.signal,
            effect=result.effects.get(c.signal, ""),
            explained_percent=c.explained_percent,
            time_constant_s=c.time_constant_s,
            gain_um_per_unit=c.gain_um_per_unit,
            sign=c.sign,
            lag_s=c.lag_s,
            xcorr_peak=c.xcorr_peak,
            xcorr_bound=c.xcorr_bound,
            significant=c.significant,
        )
        for c in result.diagnosis.candidates
    ]


def residue_white(result: DiagnosisResult | str) -> bool:
    """Whether the residue is indistinguishable from white noise (nothing left to model)."""
    return not isinstance(result, str) and result.diagnosis.residue_white


def verdict(result: DiagnosisResult | str) -> str:
    """The diagnosis in one sentence, or why there is none."""
    return f"no candidate ranking: {result}" if isinstance(result, str) else result.verdict


def notes(result: DiagnosisResult | str) -> Sequence[str]:
    """What the diagnosis left out and why (constant columns)."""
    return () if isinstance(result, str) else result.notes
