"""Small numba helpers shared by every generated system module."""

from __future__ import annotations

import numpy as np
from numba import njit

# Bits of the per-row status flag returned by the generated kernels.
FLAG_SINGULAR = 1  #: C was singular or ill-conditioned at some evaluation (the law's u was set to 0).
FLAG_NONFINITE = 2  #: the state became non-finite.


@njit(cache=True)
def solve_small(a: np.ndarray, b: np.ndarray, x: np.ndarray, tol: float) -> int:
    """Solve ``a x = b`` for a small square ``a`` by Gaussian elimination with partial pivoting.

    ``a`` and ``b`` are overwritten.  Returns ``FLAG_SINGULAR`` (and ``x = 0``) when a pivot is
    not larger than ``tol * max(1, max|a|)`` or is NaN, else 0.
    """
    m = a.shape[0]
    scale = 1.0
    for i in range(m):
        for j in range(m):
            v = abs(a[i, j])
            if v > scale:
                scale = v
    thresh = tol * scale
    for k in range(m):
        piv = k
        best = abs(a[k, k])
        for i in range(k + 1, m):
            v = abs(a[i, k])
            if v > best:
                best = v
                piv = i
        if not best > thresh:  # also true for NaN
            for i in range(m):
                x[i] = 0.0
            return FLAG_SINGULAR
        if piv != k:
            for j in range(m):
                tmp = a[k, j]
                a[k, j] = a[piv, j]
                a[piv, j] = tmp
            tmp = b[k]
            b[k] = b[piv]
            b[piv] = tmp
        for i in range(k + 1, m):
            f = a[i, k] / a[k, k]
            for j in range(k, m):
                a[i, j] -= f * a[k, j]
            b[i] -= f * b[k]
    for i in range(m - 1, -1, -1):
        acc = b[i]
        for j in range(i + 1, m):
            acc -= a[i, j] * x[j]
        x[i] = acc / a[i, i]
    return 0
