"""The figures in compd's tables: rounded as asked, undefined as n/a, and never a negative zero."""

from __future__ import annotations

import math

from compd.toolkit.summary import fmt


def test_a_figure_that_rounds_to_zero_has_no_minus_sign() -> None:
    """-0.04 at one digit is "0.0" and -0.4 at none is "0", as -0.0 is: a table never shows "-0 %"."""
    assert fmt(-0.04, 1) == "0.0"
    assert fmt(-0.4, 0) == "0"
    assert fmt(-0.0) == "0.00"


def test_other_figures_keep_their_sign_and_undefined_is_na() -> None:
    """-0.06 at one digit stays "-0.1"; None and NaN are "n/a"."""
    assert fmt(-0.06, 1) == "-0.1"
    assert fmt(12.345, 1) == "12.3"
    assert fmt(None) == fmt(math.nan) == "n/a"
