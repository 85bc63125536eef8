"""Numba helpers of the generated kernels: status flags, a small linear solve and inline sin/cos.

Task authors may call :func:`psin`, :func:`pcos` and :func:`psincos` in their own kernels (they are
re-exported by :mod:`vnhc_gym.kernels`): the generated system code uses them for every sine and
cosine, so a task that computes the same quantity with them gets the same bits.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["FLAG_NONFINITE", "FLAG_SINGULAR", "SINCOS_MAX_ARG", "pcos", "psin", "psincos", "solve_blocks"]

# Bits of the per-row status flag returned by the generated kernels.
FLAG_SINGULAR = 1  #: C was singular or ill-conditioned at some evaluation (the law's u was set to 0).
FLAG_NONFINITE = 2  #: the state became non-finite.


@njit(cache=True)
def solve_blocks(c: np.ndarray, b: np.ndarray, x: np.ndarray, tol: float) -> int:
    """Solve ``C x = b`` for a block-diagonal ``C`` stored by block rows, by Gaussian elimination with
    partial pivoting in each block.

    ``c`` has shape ``(m, k)``: rows ``i k .. (i + 1) k - 1`` hold the ``i``-th ``k x k`` diagonal
    block (``k = m``: a full matrix; ``k = 1``: a diagonal one).  ``c`` and ``b`` are overwritten.
    Returns ``FLAG_SINGULAR`` (and ``x = 0``) when a pivot is not larger than ``tol * max|C|``
    (relative to the matrix's own scale, so multiplying ``C`` by any nonzero number never changes
    the verdict), when ``C`` is zero, or when an entry is not finite; else 0.
    """
    m, k = c.shape
    scale = 0.0
    finite = True
    for i in range(m):
        for j in range(k):
            v = abs(c[i, j])
            if not v < np.inf:  # inf or NaN
                finite = False
            elif v > scale:
                scale = v
    thresh = tol * scale
    ok = finite and scale > 0.0
    for blk in range(0, m, k):
        if not ok:
            break
        for col in range(k):  # eliminate below the pivot of column col of this block
            piv = blk + col
            best = abs(c[piv, col])
            for i in range(blk + col + 1, blk + k):
                v = abs(c[i, col])
                if v > best:
                    best = v
                    piv = i
            if not best > thresh:
                ok = False
                break
            row = blk + col
            if piv != row:
                for j in range(k):
                    tmp = c[row, j]
                    c[row, j] = c[piv, j]
                    c[piv, j] = tmp
                tmp = b[row]
                b[row] = b[piv]
                b[piv] = tmp
            for i in range(row + 1, blk + k):
                f = c[i, col] / c[row, col]
                for j in range(col, k):
                    c[i, j] -= f * c[row, j]
                b[i] -= f * b[row]
        if ok:
            for col in range(k - 1, -1, -1):
                acc = b[blk + col]
                for j in range(col + 1, k):
                    acc -= c[blk + col, j] * x[blk + j]
                x[blk + col] = acc / c[blk + col, col]
    if not ok:
        for i in range(m):
            x[i] = 0.0
        return FLAG_SINGULAR
    return 0


# --- sin and cos as branch-free inline polynomials -------------------------------------------------
# Why not math.sin: numba calls libm for it, and a call stops LLVM from vectorising the generated
# row-block loops (about 3x for the USV's RK4).  These are fdlibm's kernels on [-pi/4, pi/4]
# (the coefficients of musl's __sin.c and __cos.c) after a Cody-Waite reduction by pi/2 in three
# parts, with the quadrant chosen by selects, so a loop over rows becomes SIMD code.  Error: below
# 1e-15 absolute for |x| <= SINCOS_MAX_ARG (tests/test_codegen.py checks it against math.sin);
# beyond it the reduction loses accuracy, and inf or NaN give NaN as libm does.
SINCOS_MAX_ARG = 1.0e6
_INVPIO2 = 6.36619772367581382433e-01
_PIO2_1 = 1.57079632673412561417e00  # first 33 bits of pi/2: n * _PIO2_1 is exact for |n| < 2**20
_PIO2_2 = 6.07710050630396597660e-11  # next 33 bits
_PIO2_2T = 2.02226624879595063154e-21  # pi/2 - (_PIO2_1 + _PIO2_2)
_S1, _S2, _S3 = -1.66666666666666324348e-01, 8.33333333332248946124e-03, -1.98412698298579493134e-04
_S4, _S5, _S6 = 2.75573137070700676789e-06, -2.50507602534068634195e-08, 1.58969099521155010221e-10
_C1, _C2, _C3 = 4.16666666666666019037e-02, -1.38888888888741095749e-03, 2.48015872894767294178e-05
_C4, _C5, _C6 = -2.75573143513906633035e-07, 2.08757232129817482790e-09, -1.13596475577881948265e-11


@njit(cache=True, inline="always", error_model="numpy")
def _sincos_kernel(x: float) -> tuple[float, float, int]:
    """``(sin r, cos r, n mod 4)`` with ``x = n pi/2 + r``, ``|r| <= pi/4``."""
    n = np.rint(x * _INVPIO2)
    r = ((x - n * _PIO2_1) - n * _PIO2_2) - n * _PIO2_2T
    z = r * r
    s = r + r * z * (_S1 + z * (_S2 + z * (_S3 + z * (_S4 + z * (_S5 + z * _S6)))))
    hz = 0.5 * z
    w = 1.0 - hz
    c = w + (((1.0 - w) - hz) + z * z * (_C1 + z * (_C2 + z * (_C3 + z * (_C4 + z * (_C5 + z * _C6))))))
    return s, c, int(np.int32(n) & 3)  # int32: AVX2 converts doubles to int32 in SIMD, not to int64


@njit(cache=True, inline="always", error_model="numpy")
def psincos(x: float) -> tuple[float, float]:
    """``(sin(x), cos(x))`` as inline, vectorisable code with one shared reduction (see the note
    above ``SINCOS_MAX_ARG``)."""
    s, c, q = _sincos_kernel(x)
    vs = c if q & 1 else s
    vc = -s if q & 1 else c
    return (-vs if q & 2 else vs), (-vc if q & 2 else vc)


@njit(cache=True, inline="always", error_model="numpy")
def psin(x: float) -> float:
    """``sin(x)``: ``psincos(x)[0]`` (inlined, the unused half is optimised away)."""
    return psincos(x)[0]


@njit(cache=True, inline="always", error_model="numpy")
def pcos(x: float) -> float:
    """``cos(x)``: ``psincos(x)[1]``."""
    return psincos(x)[1]
