"""The simulated run's closing table: figures as a reader takes them."""

from rich.console import Console

from compd.sim.plc.machine import AxisSummary
from compd.sim.plc.view import summary_table


def _printed(row: AxisSummary) -> str:
    console = Console(width=120, record=True, color_system=None)
    console.print(summary_table([row]))
    return console.export_text()


def test_an_axis_that_did_not_move_prints_no_minus_zero() -> None:
    """A reduction of -0.04 % (compensation that changed nothing) reads 0.0 %, never "-0.0 %"."""
    row = AxisSummary("x", 1.0, 1.0004, 3.0, 3.0, 1.5, 1.5, 0.0)
    assert row.reduction_pct < 0.0
    text = _printed(row)
    assert "0.0 %" in text and "-0.0" not in text


def test_the_figures_are_the_axis_summary_s() -> None:
    """RMS, p-p and max |e| with two decimals, uncompensated beside compensated, and the reduction."""
    text = _printed(AxisSummary("z", 57.01, 0.54, 120.5, 3.25, 80.125, 2.0, 0.1))
    for figure in ("57.01", "0.54", "120.50", "3.25", "80.12", "2.00", "99.1 %"):
        assert figure in text
