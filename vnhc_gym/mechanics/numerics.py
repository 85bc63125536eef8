"""Numba helpers of the generated system kernels (the baselines' model): status flags, the
transversality measure of the law's singular test, a small linear solve and inline sin/cos (the
generated code uses them for every sine and cosine).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["FLAG_NONFINITE", "FLAG_SINGULAR", "SINCOS_MAX_ARG", "pcos", "psin", "psincos", "solve_blocks",
           "transversality", "transversality_diagonal", "transversality_pairs"]

# Bits of the per-row status flag returned by the generated kernels.
FLAG_SINGULAR = 1  #: the input fields were (nearly) tangent to the constraint at some evaluation (u* set to 0).
FLAG_NONFINITE = 2  #: the state became non-finite.

#: Largest number of Jacobi sweeps for a block of size 3 or more (convergence is quadratic: a few do).
_JACOBI_SWEEPS = 60

# The measures are inlined into their callers (numba's IR inlining) and their loops have no early
# exit: as a call with array arguments, or with a return inside the loop, the test would cost
# several times the rest of the law on a diagonal C.  Degenerate and non-finite inputs show up as a
# NaN or inf ratio and are sorted out afterwards, off the hot path, by _degenerate.


@njit(cache=True, error_model="numpy", inline="always")
def transversality(c: np.ndarray, sizes: np.ndarray) -> float:
    """How far a block-diagonal ``C`` is from singular, relative to the factors it is built from.

    ``C^{ba} = J_b . Y^a`` pairs the rows ``J_b = d phi^b / d qd`` with the input fields ``Y^a``.
    ``sizes`` holds their squared sizes in the metric: ``sizes[b] = J_b M^-1 J_b^T`` and
    ``sizes[m + a] = Y^a . M Y^a`` (``2 m`` entries).  The measure is the smallest singular value
    of the normalised matrix ``C^{ba} / (|J_b| |Y^a|)``, over the diagonal blocks of ``C`` (stored
    by block rows in ``c``, shape ``(m, k)``, as in `solve_blocks`).  Each normalised entry
    is the cosine of the angle, in the metric, between the gradient of ``phi^b`` and ``Y^a``
    (Cauchy-Schwarz), so the measure lies in ``[0, 1]`` up to rounding; it is 0 where the inputs
    are tangent to the constraint, and it does not change when masses, units, constraint
    components or controls are rescaled.

    Closed forms for blocks of size 1 (`transversality_diagonal`) and 2
    (`transversality_pairs`), one-sided Jacobi rotations for larger blocks.  Returns 0 when
    a row of ``d phi/d qd`` or an input field has zero size (that row or column of ``C`` is zero
    too), NaN when an entry or a size is not finite.  Nothing is modified.
    """
    k = c.shape[1]
    if k == 1:
        return transversality_diagonal(c, sizes)
    if k == 2:
        return transversality_pairs(c, sizes)
    return _transversality_jacobi(c, sizes)


@njit(cache=True, error_model="numpy", inline="always")
def transversality_diagonal(c: np.ndarray, sizes: np.ndarray) -> float:
    """`transversality` of a diagonal ``C`` (``c`` of shape ``(m, 1)``): the smallest
    ``|C^{bb}| / (|J_b| |Y^b|)``."""
    m = c.shape[0]
    rho = np.inf
    ok = True
    for i in range(m):
        a = sizes[i]
        b = sizes[m + i]
        # sqrt of each factor, not of the product: the product of two squared sizes can overflow.
        r = abs(c[i, 0]) / (math.sqrt(a) * math.sqrt(b))
        ok &= (r < np.inf) & (a < np.inf) & (b < np.inf)  # False for NaN too
        rho = min(rho, r)
    return rho if ok else _degenerate(c, sizes)


@njit(cache=True, error_model="numpy", inline="always")
def transversality_pairs(c: np.ndarray, sizes: np.ndarray) -> float:
    """`transversality` of a ``C`` made of ``2 x 2`` diagonal blocks (``c`` of shape ``(m, 2)``).

    For a ``2 x 2`` matrix ``sigma_min = |det| / sigma_max`` with
    ``sigma_max^2 = (F + sqrt(F^2 - 4 det^2)) / 2`` and ``F`` the squared Frobenius norm; the
    normalised entries are cosines, so nothing here over- or underflows unless a block is zero."""
    m = c.shape[0]
    rho = np.inf
    ok = True
    for blk in range(0, m, 2):
        sj0 = math.sqrt(sizes[blk])
        sj1 = math.sqrt(sizes[blk + 1])
        sy0 = math.sqrt(sizes[m + blk])
        sy1 = math.sqrt(sizes[m + blk + 1])
        a00 = c[blk, 0] / (sj0 * sy0)
        a01 = c[blk, 1] / (sj0 * sy1)
        a10 = c[blk + 1, 0] / (sj1 * sy0)
        a11 = c[blk + 1, 1] / (sj1 * sy1)
        det = a00 * a11 - a01 * a10
        f = a00 * a00 + a01 * a01 + a10 * a10 + a11 * a11
        smax = math.sqrt(0.5 * (f + math.sqrt(max(f * f - 4.0 * det * det, 0.0))))
        r = abs(det) / smax  # NaN for a zero block (0 / 0)
        ok &= (r < np.inf) & (sj0 < np.inf) & (sj1 < np.inf) & (sy0 < np.inf) & (sy1 < np.inf)
        rho = min(rho, r)
    return rho if ok else _degenerate(c, sizes)


@njit(cache=True, error_model="numpy")
def _finite(c, sizes):
    """Whether every entry of ``c`` and every size is finite."""
    m, k = c.shape
    for i in range(m):
        if not (sizes[i] < np.inf and sizes[m + i] < np.inf):
            return False
        for j in range(k):
            if not abs(c[i, j]) < np.inf:
                return False
    return True


@njit(cache=True, error_model="numpy")
def _degenerate(c, sizes):
    """The measure where a closed form met a NaN or inf ratio: NaN if an entry of ``c`` or a size is
    not finite; else 0 (a size or a block is zero: a row or column of ``C`` vanishes)."""
    return 0.0 if _finite(c, sizes) else np.nan


@njit(cache=True, error_model="numpy")
def _transversality_jacobi(c, sizes):
    """`transversality` for blocks of any size, by one-sided Jacobi rotations."""
    if not _finite(c, sizes):
        return np.nan
    m, k = c.shape
    t = np.empty((k, k))  # the normalised block being rotated (only systems with blocks of 3 or more)
    rho = np.inf
    for blk in range(0, m, k):
        degenerate = False
        for i in range(blk, blk + k):
            if not (sizes[i] > 0.0 and sizes[m + i] > 0.0):
                degenerate = True
        r = 0.0 if degenerate else _jacobi_smin(c, sizes, t, blk)
        rho = min(rho, r)
    return rho


@njit(cache=True, error_model="numpy")
def _jacobi_smin(c, sizes, t, blk):
    """Smallest singular value of the normalised block at rows ``blk .. blk + k - 1`` (see
    `transversality`), by one-sided Jacobi rotations of its columns in ``t`` (``k x k``)."""
    m, k = c.shape
    for i in range(k):
        si = math.sqrt(sizes[blk + i])
        for j in range(k):
            t[i, j] = c[blk + i, j] / (si * math.sqrt(sizes[m + blk + j]))
    eps = 2.220446049250313e-16
    for _ in range(_JACOBI_SWEEPS):
        rotated = False
        for p in range(k - 1):
            for q in range(p + 1, k):
                alpha = 0.0
                beta = 0.0
                gamma = 0.0
                for i in range(k):
                    alpha += t[i, p] * t[i, p]
                    beta += t[i, q] * t[i, q]
                    gamma += t[i, p] * t[i, q]
                if gamma == 0.0 or abs(gamma) <= eps * math.sqrt(alpha * beta):
                    continue  # columns p and q are already orthogonal to rounding
                rotated = True
                zeta = (beta - alpha) / (2.0 * gamma)
                tn = (1.0 if zeta >= 0.0 else -1.0) / (abs(zeta) + math.hypot(1.0, zeta))
                cs = 1.0 / math.sqrt(1.0 + tn * tn)
                sn = cs * tn
                for i in range(k):
                    xp = t[i, p]
                    xq = t[i, q]
                    t[i, p] = cs * xp - sn * xq
                    t[i, q] = sn * xp + cs * xq
        if not rotated:
            break
    smin = np.inf
    for j in range(k):
        acc = 0.0
        for i in range(k):
            acc += t[i, j] * t[i, j]
        smin = min(smin, math.sqrt(acc))
    return smin


@njit(cache=True)
def solve_blocks(c: np.ndarray, b: np.ndarray, x: np.ndarray, tol: float) -> int:
    """Solve ``C x = b`` for a block-diagonal ``C`` stored by block rows, by Gaussian elimination with
    partial pivoting in each block.

    ``c`` has shape ``(m, k)``: rows ``i k .. (i + 1) k - 1`` hold the ``i``-th ``k x k`` diagonal
    block (``k = m``: a full matrix; ``k = 1``: a diagonal one).  ``c`` and ``b`` are overwritten.
    Returns ``FLAG_SINGULAR`` (and ``x = 0``) when a pivot is not larger than ``tol * max|C|``
    (relative to the matrix's own scale, so multiplying ``C`` by any nonzero number never changes
    the verdict), when ``C`` is zero, or when an entry is not finite; else 0.  The law decides
    whether ``C`` is singular with `transversality` first and then calls this with
    ``tol = 0`` (only an exactly zero pivot is refused): the same arithmetic, whatever the test.
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
