"""The table of what the sensors cannot verify, as ``compd fit``, ``model check`` and ``check-config`` print it.

One row per model input and axis (:mod:`compd.model.verifiable`): the
detector's threshold in the input's unit, the axis's static sensitivity, their
product (the offset error a wrong reading causes unseen) against the axis's
tolerance, and the remedy where it is beyond. Information, not an error: the
commands' exit status does not change.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

from rich.console import Console
from rich.table import Table
from rich.text import Text

from compd.cli.tablefit import fit_table
from compd.model.verifiable import Unverifiable


def _figure(value: float, digits: int = 3) -> str:
    return "-" if not math.isfinite(value) else f"{value:.{digits}g}"


def verifiable_table(rows: Sequence[Unverifiable], units: Mapping[str, str]) -> Table:
    """The rows as a table: input, unit, detected by, threshold, axis, um/unit, undetectable um, tolerance, verdict."""
    table = Table(
        "input",
        "unit",
        "detected by",
        "threshold",
        "axis",
        "um/unit",
        "undetectable (um)",
        "tolerance (um)",
        "verdict",
        title="what the sensors can verify: a wrong reading below the threshold passes every check",
    )
    for r in rows:
        undetectable = "any" if math.isinf(r.undetectable_um) else f"{r.undetectable_um:.1f}"
        verdict = (
            Text(f"not verifiable: {r.remedy}", style="bold red")
            if r.exceeds
            else Text("ok", style="green")
        )
        table.add_row(
            r.input,
            units.get(r.input, ""),
            r.detection.by,
            _figure(r.detection.threshold),
            r.axis,
            _figure(r.um_per_unit, 4),
            undetectable,
            f"{r.tolerance_um:.3g}",
            verdict,
        )
    return table


def print_verifiable(
    out: Console, rows: Sequence[Unverifiable], units: Mapping[str, str], note: str = ""
) -> None:
    """Print the table and one line saying what it means (``note``: on what it assumed)."""
    if not rows:
        return
    out.print(fit_table(verifiable_table(rows, units), out))
    beyond = [r for r in rows if r.exceeds]
    summary = (
        f"{len(beyond)} of {len(rows)} input(s) x axes cannot be verified to the axis's tolerance: "
        "a redundant sensor beside the input, or probes on the axis, see what the others cannot"
        if beyond
        else "every input is verified to its axis's tolerance"
    )
    out.print(summary + (f" ({note})" if note else ""))
