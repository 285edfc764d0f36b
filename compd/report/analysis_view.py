"""What the report reads from ``compd.toolkit.analysis`` results, in one place.

Failing windows and the candidate ranking are computed by ``compd.toolkit.analysis``
(the same functions ``compd compare`` and ``compd diagnose`` call, so all
three say the same thing); the report only shows them. A diagnosis may be
missing with a reason (a record too short to cross-validate, no candidate
signal): then the reason is shown instead.
"""

from __future__ import annotations

from collections.abc import Sequence

from compd.model.diagnose import CandidateScore
from compd.model.windows import FailingWindow
from compd.toolkit.analysis import DiagnosisResult, WindowsResult


def windows(result: WindowsResult) -> Sequence[FailingWindow]:
    """The failing windows, in time order."""
    return result.windows


def tolerance_um(result: WindowsResult) -> float:
    """The residue RMS above which a window fails, in um."""
    return result.tolerance_um


def candidates(result: DiagnosisResult | str) -> Sequence[CandidateScore]:
    """Candidates best first; none when the diagnosis could not be made."""
    return () if isinstance(result, str) else result.diagnosis.candidates


def effect(result: DiagnosisResult | str, signal: str) -> str:
    """The physical effect the catalogue names for ``signal`` ("" when none)."""
    return "" if isinstance(result, str) else result.effects.get(signal, "")


def residue_white(result: DiagnosisResult | str) -> bool:
    """Whether the residue is indistinguishable from white noise (nothing left to model)."""
    return not isinstance(result, str) and result.diagnosis.residue_white


def verdict(result: DiagnosisResult | str) -> str:
    """The diagnosis in one sentence, or why there is none."""
    return f"no candidate ranking: {result}" if isinstance(result, str) else result.verdict


def notes(result: DiagnosisResult | str) -> Sequence[str]:
    """What the diagnosis left out and why (constant columns)."""
    return () if isinstance(result, str) else result.notes
