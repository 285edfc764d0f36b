"""A discrete TF run over a sequence in numpy alone: the daemon's ``lfilter`` without scipy.

The recursion is the transposed direct form II of :mod:`compd.model.compiled`,
with ``a0 = 1`` after dividing both polynomials by it::

    y(k)     = z_0(k-1) + b_0 u(k)
    z_i(k)   = z_{i+1}(k-1) + b_{i+1} u(k) - a_{i+1} y(k)      (i < n-1)
    z_{n-1}(k) = b_n u(k) - a_n y(k)

evaluated in the order ``scipy.signal.lfilter`` evaluates it (its C loop,
operation by operation), so both give the same floating-point numbers. The
daemon loads scipy for nothing else (~100 MB resident), so where scipy is not
already loaded a model is run here, one sample at a time in Python: ~1 us per
coefficient and sample, enough for the checks at compilation (1000 samples)
and for a warm hand-over (a shift of 1 s ticks, tens of ms per sub-model).
Where scipy is loaded (the modelling toolkit, over records of millions of
samples) its compiled loop runs, and the numbers are the same.
"""

from __future__ import annotations

import sys

import numpy as np


def lfilter(
    b: np.ndarray, a: np.ndarray, u: np.ndarray, zi: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """``y`` for the input ``u`` and the final state, from the state ``zi`` (zeros if None).

    ``b`` and ``a`` are ascending powers of ``z^-1``, ``a[0] != 0``; the state
    has ``max(len(b), len(a)) - 1`` entries, as ``scipy.signal.lfilter``'s ``zi``.
    """
    b = np.asarray(b, dtype=float)
    a = np.asarray(a, dtype=float)
    u = np.asarray(u, dtype=float)
    size = max(b.size, a.size)
    b = np.pad(b, (0, size - b.size))
    a = np.pad(a, (0, size - a.size))
    z0 = np.zeros(size - 1) if zi is None else np.asarray(zi, dtype=float)
    signal = sys.modules.get("scipy.signal")
    if signal is not None and size > 1:
        y, zf = signal.lfilter(b, a, u, zi=z0)
        return np.asarray(y), np.asarray(zf)
    return _stepped(b / a[0], a / a[0], u, z0)


def _stepped(
    b: np.ndarray, a: np.ndarray, u: np.ndarray, zi: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The recursion of the module's docstring, sample by sample on Python floats (IEEE doubles)."""
    n = b.size
    bs, as_, z = b.tolist(), a.tolist(), zi.tolist()
    y = [0.0] * u.size
    b0 = bs[0]
    if n == 1:
        return u * b0, np.zeros(0)
    last = n - 1
    for k, x in enumerate(u.tolist()):
        yk = z[0] + b0 * x
        for i in range(last - 1):
            z[i] = z[i + 1] + x * bs[i + 1] - yk * as_[i + 1]
        z[last - 1] = x * bs[last] - yk * as_[last]
        y[k] = yk
    return np.array(y), np.array(z)
