"""Batch kernels of a compiled system: the stabilising law, RK4 with or without it, phi and friends.

This file is the template of every generated system module.  Code generation copies its text and
replaces the import between the ``system`` markers below with one system's expression functions
and constants (`vnhc_gym.mechanics.codegen.generate_source`); everything else is the same
for every system.  Imported as it is, it runs on the placeholder system of
`vnhc_gym.mechanics._placeholder_system` (a point mass on a line), which the tests use.

States are rows ``s = (q, qd)`` of length ``2 N``; parameters rows of length ``NP``; controls rows
of length ``M``.  Every batched kernel takes ``(B, ...)`` arrays and loops over rows; the per-row
functions (``rk4_row``, ``law_row`` and the expression functions) are what the environments'
step kernels call.
"""

import math  # noqa: F401  (the generated expression functions use it)
from typing import NamedTuple

import numpy as np
from numba import njit

from vnhc_gym.mechanics.numerics import (  # noqa: F401  (generated code: psin, pcos)
    FLAG_NONFINITE,
    FLAG_SINGULAR,
    pcos,
    psin,
    solve_blocks,
    transversality,
    transversality_diagonal,
    transversality_pairs,
)

# isort: split
# --- system: begin (code generation writes one system's functions and constants here)
from vnhc_gym.mechanics._placeholder_system import (  # noqa: F401
    BLOCK,
    HOLONOMIC,
    NAME,
    NAUX,
    NG,
    NP,
    OUTPUT_NAMES,
    PARAM_DEFAULTS,
    PARAM_NAMES,
    PARAM_POSITIVE,
    M,
    N,
    _accel,
    _accel_at,
    _aux,
    _aux_at,
    _cg,
    _cgn,
    _dyn,
    _energy,
    _phi,
    _phi_at,
    _phi_h,
    _tn,
)

# --- system: end
# isort: split

#: Feedback modes of `rk4_row`: the held control only; ``u*`` re-evaluated at every RK4 stage
#: (the theorem's setting); ``u*`` evaluated once at the start of the control period and held.
OPEN, CONTINUOUS, SAMPLED = 0, 1, 2

# --- rows: begin (a fleet brings its own row kernels, built on its unit's: see _fleet.py)


class Work(NamedTuple):
    """Scratch vectors of one row's RK4 step and law (views of one allocation, see `work`)."""

    x: np.ndarray  # the state being integrated (2N)
    tmp: np.ndarray  # an RK4 stage's state (2N)
    k1: np.ndarray  # stage derivatives (2N each)
    k2: np.ndarray
    k3: np.ndarray
    k4: np.ndarray  # (also the squared sizes of the law's singular test while the law runs, see _sizes)
    u: np.ndarray  # the control of the current stage (M)
    base: np.ndarray  # the held part of the control (M)
    law: np.ndarray  # u* at a stage (M)
    acc: np.ndarray  # sum of the applied controls over substeps (M)
    G: np.ndarray  # G(phi), then the law's right-hand side (M)
    ph: np.ndarray  # phi (M)
    hol: np.ndarray  # phi_h (M)
    C: np.ndarray  # decoupling matrix by block rows (M x BLOCK, see solve_blocks)


@njit(cache=True)
def work() -> Work:
    """Scratch space for `rk4_row` and `law_row`: one allocation, reused row after row."""
    n2 = 2 * N
    flat = np.empty(6 * n2 + 7 * M + M * BLOCK)
    o = 6 * n2
    return Work(flat[0:n2], flat[n2:2 * n2], flat[2 * n2:3 * n2], flat[3 * n2:4 * n2], flat[4 * n2:5 * n2],
                flat[5 * n2:6 * n2], flat[o:o + M], flat[o + M:o + 2 * M], flat[o + 2 * M:o + 3 * M],
                flat[o + 3 * M:o + 4 * M], flat[o + 4 * M:o + 5 * M], flat[o + 5 * M:o + 6 * M],
                flat[o + 6 * M:o + 7 * M], flat[o + 7 * M:o + 7 * M + M * BLOCK].reshape((M, BLOCK)))


@njit(cache=True, inline="always")
def _sizes(w):
    """Where the law keeps the squared sizes of its singular test (``2 M`` entries, see
    ``transversality``): in ``w.k4``, which no RK4 stage uses while the law is evaluated (stage 4
    writes it after its law), so ``Work`` needs no further vector.  (Every array of ``Work`` costs
    reference counting at each call that passes it.)  A system with more controls than coordinates
    (its ``C`` is always singular) gets a vector of its own."""
    return w.k4 if M <= N else np.empty(2 * M)


@njit(cache=True, error_model="numpy", inline="always")
def _measure(c, sizes):
    """The transversality measure of ``c`` (see ``transversality``), by the closed form of the
    module's block size (a constant: only one form is compiled in)."""
    if BLOCK == 1:
        return transversality_diagonal(c, sizes)
    if BLOCK == 2:
        return transversality_pairs(c, sizes)
    return transversality(c, sizes)


@njit(cache=True, error_model="numpy")
def law_row(s, p, k, tol, w, u):
    """``u = C^-1 (-K phi - G)`` at state ``s`` (``-K1 phi_h - K2 psi - G`` if holonomic).

    Returns ``FLAG_SINGULAR`` (and ``u = 0``) where the input fields are (nearly) tangent to the
    constraint: where the measure of ``transversality`` is not above ``tol`` (or not finite), else 0.
    Overwrites ``w.k4`` (see `_sizes`).
    """
    sizes = _sizes(w)
    _cgn(s, p, w.C, w.G, sizes)
    _phi(s, p, w.ph)
    if HOLONOMIC:
        _phi_h(s, p, w.hol)
        for b in range(M):
            w.G[b] = -k[b] * w.hol[b] - k[M + b] * w.ph[b] - w.G[b]
    else:
        for b in range(M):
            w.G[b] = -k[b] * w.ph[b] - w.G[b]
    if not _measure(w.C, sizes) > tol:
        for a in range(M):
            u[a] = 0.0
        return FLAG_SINGULAR
    # The verdict is taken: the solve refuses only an exactly zero pivot.
    return solve_blocks(w.C, w.G, u, 0.0)


@njit(cache=True, error_model="numpy")
def _feedback(s, pl, k, lo, hi, tol, w):
    """The control of one RK4 stage of the continuous mode at state ``s``: ``clip(u*(s) + base)``
    into ``w.u``.  Returns the law's flag."""
    flag = law_row(s, pl, k, tol, w, w.law)
    for a in range(M):
        w.u[a] = min(max(w.law[a] + w.base[a], lo[a]), hi[a])
    return flag


@njit(cache=True)
def rk4_row(s, p, pl, uh, k, mode, lo, hi, dt, substeps, tol, out, u_out, w):
    """One control period ``dt`` of ``substeps`` RK4 steps from state ``s``, into ``out``.

    ``p`` drives the dynamics; ``pl`` (the model a controller is told) is what the law uses.  The
    control at each stage is ``clip(uh)`` (``OPEN``), ``clip(u*(stage) + uh)`` (``CONTINUOUS``) or
    ``clip(u*(start) + uh)`` held over the period (``SAMPLED``), with bounds ``lo``, ``hi``.
    ``u_out`` gets the applied control averaged over the substeps' first stages.  Returns the
    row's flags: ``FLAG_SINGULAR`` if the law met a singular ``C`` (it is 0 there), and
    ``FLAG_NONFINITE`` if the new state is not finite.

    Why two integrators: a held control (``OPEN``, ``SAMPLED``) needs no law inside the stages; kept
    out of that loop, the law's calls no longer slow it, and a step kernel that calls
    `rk4_held_row` directly in the ``OPEN`` mode runs about twice as fast per row.
    """
    if mode == OPEN:
        return rk4_held_row(s, p, uh, lo, hi, dt, substeps, out, u_out, w)
    return _rk4_feedback(s, p, pl, uh, k, mode, lo, hi, dt, substeps, tol, out, u_out, w)


@njit(cache=True, error_model="numpy")
def _rk4_feedback(s, p, pl, uh, k, mode, lo, hi, dt, substeps, tol, out, u_out, w):
    """`rk4_row` with the law: held from the period's start (``SAMPLED``) or at every stage."""
    if mode == SAMPLED:
        flag = law_row(s, pl, k, tol, w, w.law)
        for a in range(M):
            w.base[a] = uh[a] + w.law[a]
        return flag | rk4_held_row(s, p, w.base, lo, hi, dt, substeps, out, u_out, w)
    return _rk4_continuous(s, p, pl, uh, k, lo, hi, dt, substeps, tol, out, u_out, w)


@njit(cache=True, error_model="numpy")
def rk4_held_row(s, p, uh, lo, hi, dt, substeps, out, u_out, w):
    """`rk4_row` with the control ``clip(uh)`` held over the period (the ``OPEN`` mode)."""
    x = w.x
    tmp = w.tmp
    k1 = w.k1
    k2 = w.k2
    k3 = w.k3
    k4 = w.k4
    u = w.u
    acc = w.acc
    for i in range(2 * N):
        x[i] = s[i]
    for a in range(M):
        u[a] = min(max(uh[a], lo[a]), hi[a])
        acc[a] = 0.0
    h = dt / substeps
    for _ in range(substeps):
        for a in range(M):
            acc[a] += u[a]
        _slope(x, p, u, k1)
        _shift(x, 0.5 * h, k1, tmp)
        _slope(tmp, p, u, k2)
        _shift(x, 0.5 * h, k2, tmp)
        _slope(tmp, p, u, k3)
        _shift(x, h, k3, tmp)
        _slope(tmp, p, u, k4)
        _combine(x, h, k1, k2, k3, k4)
    for a in range(M):
        u_out[a] = acc[a] / substeps
    return _store(x, out)


@njit(cache=True, error_model="numpy")
def _rk4_continuous(s, p, pl, uh, k, lo, hi, dt, substeps, tol, out, u_out, w):
    """`rk4_row` with the control ``clip(u*(stage) + uh)`` of every stage."""
    x = w.x
    tmp = w.tmp
    k1 = w.k1
    k2 = w.k2
    k3 = w.k3
    k4 = w.k4
    u = w.u
    acc = w.acc
    for i in range(2 * N):
        x[i] = s[i]
    flag = 0
    for a in range(M):
        acc[a] = 0.0
        w.base[a] = uh[a]
    h = dt / substeps
    for _ in range(substeps):
        flag |= _feedback(x, pl, k, lo, hi, tol, w)
        for a in range(M):
            acc[a] += u[a]
        _slope(x, p, u, k1)
        _shift(x, 0.5 * h, k1, tmp)
        flag |= _feedback(tmp, pl, k, lo, hi, tol, w)
        _slope(tmp, p, u, k2)
        _shift(x, 0.5 * h, k2, tmp)
        flag |= _feedback(tmp, pl, k, lo, hi, tol, w)
        _slope(tmp, p, u, k3)
        _shift(x, h, k3, tmp)
        flag |= _feedback(tmp, pl, k, lo, hi, tol, w)
        _slope(tmp, p, u, k4)
        _combine(x, h, k1, k2, k3, k4)
    for a in range(M):
        u_out[a] = acc[a] / substeps
    return flag | _store(x, out)


@njit(cache=True, inline="always", error_model="numpy")
def _slope(y, p, u, dy):
    """``dy = (qd, a0(y) + Y(y) u)``: the state's time derivative at ``y`` under the control ``u``."""
    for i in range(N):
        dy[i] = y[N + i]
    _accel(y, p, u, dy)


@njit(cache=True, inline="always", error_model="numpy")
def _shift(x, c, dy, out):
    """``out = x + c dy``: an RK4 stage's state."""
    for i in range(2 * N):
        out[i] = x[i] + c * dy[i]


@njit(cache=True, inline="always", error_model="numpy")
def _combine(x, h, k1, k2, k3, k4):
    """``x += h / 6 (k1 + 2 k2 + 2 k3 + k4)``: the RK4 step."""
    for i in range(2 * N):
        x[i] = x[i] + (h / 6.0) * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])


@njit(cache=True, inline="always")
def _store(x, out):
    """``out = x``; ``FLAG_NONFINITE`` if an entry is not finite, else 0."""
    finite = True
    for i in range(2 * N):
        out[i] = x[i]
        if not math.isfinite(x[i]):
            finite = False
    return 0 if finite else FLAG_NONFINITE


# --- rows: end

# ---------------------------------------------------------------------- batched kernels (rows of B)


@njit(cache=True)
def rk4(S, P, PL, U, K, mode, lo, hi, dt, substeps, tol, out, u_out, flags):
    """`rk4_row` for every row: ``S`` (B, 2N), ``P``/``PL`` (B, NP), ``U`` (B, M), ``K`` (B, NG)."""
    w = work()
    for r in range(S.shape[0]):
        flags[r] = rk4_row(S[r], P[r], PL[r], U[r], K[r], mode, lo, hi, dt, substeps, tol, out[r], u_out[r], w)


@njit(cache=True)
def law(S, P, K, tol, U, flags):
    """``u*`` for every row (``K = 0``: the invariance control); ``flags[r] = FLAG_SINGULAR`` where
    ``C`` is singular."""
    w = work()
    for r in range(S.shape[0]):
        flags[r] = law_row(S[r], P[r], K[r], tol, w, U[r])


@njit(cache=True, error_model="numpy")
def transversal(S, P, out):
    """The measure of the singular test (see ``transversality``) of every row."""
    w = work()
    for r in range(S.shape[0]):
        sizes = _sizes(w)
        _cgn(S[r], P[r], w.C, w.G, sizes)
        out[r] = _measure(w.C, sizes)


@njit(cache=True)
def phi(S, P, out):
    """``phi`` of every row."""
    for r in range(S.shape[0]):
        _phi(S[r], P[r], out[r])


@njit(cache=True)
def phi_h(S, P, out):
    """``phi_h`` of every row (holonomic constraints)."""
    for r in range(S.shape[0]):
        _phi_h(S[r], P[r], out[r])


@njit(cache=True)
def aux(S, P, out):
    """The extra outputs of every row."""
    for r in range(S.shape[0]):
        _aux(S[r], P[r], out[r])


@njit(cache=True)
def cg(S, P, C, G):
    """``C`` (by block rows, ``(B, M, BLOCK)``) and ``G(phi)`` of every row."""
    for r in range(S.shape[0]):
        _cg(S[r], P[r], C[r], G[r])


@njit(cache=True)
def dyn(S, P, A0, Y):
    """Drift ``a0`` and input fields ``Y`` of every row."""
    for r in range(S.shape[0]):
        _dyn(S[r], P[r], A0[r], Y[r])


@njit(cache=True)
def energy(S, P, out):
    """Mechanical energy of every row."""
    for r in range(S.shape[0]):
        out[r] = _energy(S[r], P[r])
