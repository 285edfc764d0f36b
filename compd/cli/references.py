"""The papers compd's methods come from, by the short names its help and messages use.

``compd help references`` prints them; help texts and messages cite a paper
by its short name (``Horejs 2015, sect. 4.3``) so that a user can look it
up here and then in a library. What the papers themselves print is given;
where the copy compd was built from carries no publication details, the
title is what to search for.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Reference:
    """One paper: its short name, authors, title, where and when it appeared, and what compd takes."""

    short: str
    authors: str
    title: str
    venue: str
    doi: str | None
    used_for: str


REFERENCES: tuple[Reference, ...] = (
    Reference(
        "Horejs 2010",
        "O. Horejš, M. Mareš, P. Kohút, P. Bárta, J. Hornych (RCMT, Czech Technical "
        "University in Prague)",
        "Compensation of machine tool thermal errors based on transfer functions",
        "MM Science Journal, 2010",
        None,
        "thermal transfer functions per heat source (continuous TFs, compd fit --method oe); "
        "the controller's linear-regression baseline y = k (T - T_base) it beats",
    ),
    Reference(
        "Horejs 2015",
        "O. Horejš, M. Mareš, J. Hornych",
        "Real-time compensation of machine tool thermal errors including cutting process",
        "Journal of Machine Engineering, 2015 (published online 11 September 2015)",
        None,
        "a TF as a difference equation (eq. 1), fit % (eq. 2) and residue (eq. 3); "
        "superposed sub-models; the missing cutting-process effect found from the residue "
        "and added (sect. 4.3: compd diagnose, compd extend)",
    ),
    Reference(
        "Post-process 2024",
        "(not printed in the copy compd was built from: see the DOI)",
        "Post-process updating of model parameters to approximate thermal errors of machine "
        "tools operating in different configurations",
        "Precision Engineering, 2024",
        "10.1016/j.precisioneng.2024.02.011",
        "ARX TFs at 1 s, heating and cooling separated by spindle rotation (eq. 5, compd fit "
        "--phase-gate); named gains g1, g2 (eq. 6, gain_schedule) updated from sparse probe "
        "measurements (eq. 7-9, compd update)",
    ),
    Reference(
        "Pahk 2002",
        "H. J. Pahk, S. W. Lee",
        "Thermal error measurement and real time compensation system for the CNC machine "
        "tools incorporating the spindle thermal error and the feed axis thermal error",
        "International Journal of Advanced Manufacturing Technology 20, 487-494, 2002",
        None,
        "regression vs neural network vs system identification (ARX best); the "
        "position-dependent feed-axis error m1(T) P + m2(T) (compd fit --position)",
    ),
    Reference(
        "Swiss-lathe paper",
        "(not printed in the copy compd was built from)",
        "Thermal compensation of sudden working space condition changes in Swiss-type lathe "
        "machining",
        "(search by title)",
        None,
        "door openings: a random forest on the ARX model's residue fed by the smoothed door "
        "signal (compd residual); EMD denoising of noisy inputs (compd fit --denoise); "
        "peak-to-peak and RMS residues",
    ),
)


def references_page() -> str:
    """``compd help references``: each paper under its short name."""
    lines = [
        "The papers compd's methods come from. compd's help and messages cite them by the",
        "short name in brackets (e.g. 'Horejs 2015, sect. 4.3').",
    ]
    for ref in REFERENCES:
        lines += ["", f"[{ref.short}]", f"  {ref.authors}", f"  {ref.title}.", f"  {ref.venue}"]
        if ref.doi:
            lines.append(f"  https://doi.org/{ref.doi}")
        lines.append(f"  compd: {ref.used_for}")
    return "\n".join(lines)
