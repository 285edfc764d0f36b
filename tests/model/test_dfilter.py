"""compd.model.dfilter: the daemon's numpy lfilter gives scipy's numbers, bit for bit, and loads no scipy."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import scipy.signal

from compd.model.dfilter import _stepped, lfilter


@pytest.mark.parametrize("order", [0, 1, 2, 3, 5])
@pytest.mark.parametrize("a0", [1.0, 2.5])
def test_stepped_recursion_equals_scipy_lfilter_exactly(order: int, a0: float) -> None:
    """Same operations in the same order as scipy's C loop: equal outputs and final states, not just close."""
    rng = np.random.default_rng(order)
    a = np.atleast_1d(np.poly(rng.uniform(0.2, 0.999, order) * rng.choice([-1.0, 1.0], order))) * a0
    b = rng.normal(size=order + 1)
    u = rng.normal(size=3000).cumsum()
    zi = rng.normal(size=order)
    y, zf = _stepped(b / a[0], a / a[0], u, zi)
    if order:
        expected_y, expected_zf = scipy.signal.lfilter(b, a, u, zi=zi)
    else:
        expected_y, expected_zf = scipy.signal.lfilter(b, a, u), np.zeros(0)
    np.testing.assert_array_equal(y, expected_y)
    np.testing.assert_array_equal(zf, expected_zf)


def test_unequal_lengths_and_no_state_are_padded_like_scipy() -> None:
    """``b`` shorter than ``a`` and ``zi=None`` (a start at rest) as ``lfilter`` takes them."""
    b, a = np.array([0.0, 0.3]), np.array([1.0, -1.5, 0.56])
    u = np.ones(200)
    y, zf = lfilter(b, a, u)
    padded = np.pad(b, (0, 1))
    stepped, stepped_zf = _stepped(padded, a, u, np.zeros(2))
    np.testing.assert_array_equal(y, scipy.signal.lfilter(b, a, u))
    np.testing.assert_array_equal(y, stepped)
    np.testing.assert_array_equal(zf, stepped_zf)


def test_without_scipy_loaded_the_numpy_recursion_runs() -> None:
    """In a process that never imported scipy (the daemon's), filtering loads none."""
    script = (
        "import sys, numpy as np\n"
        "from compd.model.dfilter import lfilter\n"
        "y, zf = lfilter(np.array([0.0, 0.5]), np.array([1.0, -0.5]), np.ones(50))\n"
        "assert abs(y[-1] - 1.0) < 1e-12, y[-1]\n"
        "print(sorted(m for m in sys.modules if m.split('.')[0] == 'scipy'))\n"
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"
