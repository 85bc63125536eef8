"""The system that `vnhc_gym.mechanics._system_template` runs on when imported as a module of its own.

A unit point mass on a line, pushed by one force, held to ``phi = qd`` (come to rest): ``n = m = 1``,
``qdd = u / mass``, ``C = 1 / mass``, ``G = 0``, one extra output (the position).  The squared sizes
of the singular test are ``J M^-1 J^T = 1 / mass`` (``J = d phi/d qd = 1``) and
``Y M Y = 1 / mass`` (``Y = 1 / mass``), so its measure is 1.  Code
generation replaces the import of this module with the same names written out for a real
system (`vnhc_gym.mechanics.codegen.generate_source`), so these functions document the
signatures that the generated ones have.
"""

from __future__ import annotations

import numpy as np
from numba import njit

NAME = "placeholder"
N = 1  #: configuration coordinates
M = 1  #: controls (= constraint components)
NP = 1  #: parameters
NG = 1  #: gains (M, or 2 M for a holonomic constraint)
NAUX = 1  #: extra outputs
HOLONOMIC = False
BLOCK = 1  #: C is block-diagonal with blocks of this size (1: diagonal; M: full), stored by block rows
PARAM_NAMES = ("mass",)
PARAM_DEFAULTS = (1.0,)
PARAM_POSITIVE = (True,)  #: whether each parameter is declared positive (the checked methods refuse <= 0)
OUTPUT_NAMES = ("position",)


@njit(cache=True, error_model="numpy")
def _accel(s: np.ndarray, p: np.ndarray, u: np.ndarray, ds: np.ndarray) -> None:
    """``ds[N:] = a0(s) + Y(s) u`` (the acceleration half of ``ds/dt``)."""
    ds[1] = u[0] / p[0]


@njit(cache=True, error_model="numpy")
def _accel_at(s: np.ndarray, p: np.ndarray, u: np.ndarray, ds: np.ndarray, si: np.ndarray, pi: np.ndarray,
              ui: np.ndarray) -> None:
    """`_accel` reading ``s[si]``, ``p[pi]``, ``u[ui]`` and writing ``ds[si[N:]]`` (the unit of a fleet)."""
    ds[si[1]] = u[ui[0]] / p[pi[0]]


@njit(cache=True, error_model="numpy")
def _phi_at(s: np.ndarray, p: np.ndarray, out: np.ndarray, si: np.ndarray, pi: np.ndarray, oi: np.ndarray) -> None:
    """`_phi` reading ``s[si]``, ``p[pi]`` and writing ``out[oi]``."""
    out[oi[0]] = s[si[1]]


@njit(cache=True, error_model="numpy")
def _aux_at(s: np.ndarray, p: np.ndarray, out: np.ndarray, si: np.ndarray, pi: np.ndarray, oi: np.ndarray) -> None:
    """`_aux` reading ``s[si]``, ``p[pi]`` and writing ``out[oi]``."""
    out[oi[0]] = s[si[0]]


@njit(cache=True, error_model="numpy")
def _phi(s: np.ndarray, p: np.ndarray, out: np.ndarray) -> None:
    """``out = phi(s)`` (``psi = d phi_h/dt`` for a holonomic constraint)."""
    out[0] = s[1]


@njit(cache=True, error_model="numpy")
def _phi_h(s: np.ndarray, p: np.ndarray, out: np.ndarray) -> None:
    """``out = phi_h(q)`` (holonomic constraints only)."""
    out[0] = 0.0


@njit(cache=True, error_model="numpy")
def _aux(s: np.ndarray, p: np.ndarray, out: np.ndarray) -> None:
    """The extra outputs."""
    out[0] = s[0]


@njit(cache=True, error_model="numpy")
def _cg(s: np.ndarray, p: np.ndarray, C: np.ndarray, G: np.ndarray) -> None:
    """``C[b, a] = d phi^b/d qd . Y^a`` (by block rows: ``C[b, a - BLOCK (b // BLOCK)]``) and
    ``G = d phi/dq . qd + d phi/d qd . a0``."""
    C[0, 0] = 1.0 / p[0]
    G[0] = 0.0


@njit(cache=True, error_model="numpy")
def _tn(s: np.ndarray, p: np.ndarray, sizes: np.ndarray) -> None:
    """The squared sizes of the singular test: ``sizes[b] = J_b M^-1 J_b^T`` with ``J = d phi/d qd``,
    then ``sizes[M + a] = Y^a . M Y^a = f^a . Y^a``."""
    sizes[0] = 1.0 / p[0]
    sizes[1] = 1.0 / p[0]


@njit(cache=True, error_model="numpy")
def _cgn(s: np.ndarray, p: np.ndarray, C: np.ndarray, G: np.ndarray, sizes: np.ndarray) -> None:
    """`_cg` and `_tn`: what the law needs besides ``phi``."""
    _cg(s, p, C, G)
    _tn(s, p, sizes)


@njit(cache=True, error_model="numpy")
def _dyn(s: np.ndarray, p: np.ndarray, a0: np.ndarray, Y: np.ndarray) -> None:
    """Drift ``a0`` and input fields ``Y`` (columns)."""
    a0[0] = 0.0
    Y[0, 0] = 1.0 / p[0]


@njit(cache=True, error_model="numpy")
def _energy(s: np.ndarray, p: np.ndarray) -> float:
    """Mechanical energy."""
    return 0.5 * p[0] * s[1] * s[1]
