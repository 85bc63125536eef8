"""Expression functions of a fleet: ``R`` copies of one unit system that share an autonomous part.

A fleet's state holds every copy's own coordinates once and the shared ones (a leader, say) once.
Copy ``b`` sees the unit state ``s[STATE_MAP[b]]`` and the unit parameters ``p[PARAM_MAP[b]]``;
its controls are ``u[b UM .. (b + 1) UM - 1]``.  Each function below calls the unit system's
compiled function copy by copy (the acceleration, ``phi`` and the extra outputs read and write the
fleet's arrays in place through the maps; the rest gathers a copy's unit state first), so the code
and its compile time do not grow with ``R``.  The system template's RK4 and law then run on the
fleet.  The shared coordinates must evolve on their own (neither the copies' coordinates nor the
controls enter their accelerations); code generation checks that.

This file is a template: code generation inserts its text into the system template
(`vnhc_gym.mechanics._system_template`) in place of a system's expression functions, with the import
between the ``unit`` markers replaced by one unit module and one fleet's maps.  Imported
as it is, it describes a fleet of two placeholder point masses.
"""

import numpy as np
from numba import njit

# isort: split
# --- unit: begin (code generation writes the unit module's import and the fleet's maps here)
from vnhc_gym.mechanics._system_template import (  # noqa: F401
    BLOCK,
    HOLONOMIC,
)
from vnhc_gym.mechanics._system_template import NAUX as UNAUX
from vnhc_gym.mechanics._system_template import NG as UNG
from vnhc_gym.mechanics._system_template import NP as UNP
from vnhc_gym.mechanics._system_template import M as UM
from vnhc_gym.mechanics._system_template import N as UN
from vnhc_gym.mechanics._system_template import _accel_at as _unit_accel_at
from vnhc_gym.mechanics._system_template import _aux_at as _unit_aux_at
from vnhc_gym.mechanics._system_template import _cg as _unit_cg
from vnhc_gym.mechanics._system_template import _dyn as _unit_dyn
from vnhc_gym.mechanics._system_template import _energy as _unit_energy
from vnhc_gym.mechanics._system_template import _phi_at as _unit_phi_at
from vnhc_gym.mechanics._system_template import _phi_h as _unit_phi_h
from vnhc_gym.mechanics._system_template import _tn as _unit_tn

NAME = "placeholder-fleet"
R = 2  #: copies of the unit
N = 2  #: the fleet's coordinates
NP = 1  #: the fleet's parameters
PARAM_NAMES = ("mass",)
PARAM_DEFAULTS = (1.0,)
PARAM_POSITIVE = (True,)
OUTPUT_NAMES = ("position_0", "position_1")
#: (R, 2 UN): the fleet-state index of each entry of copy b's unit state (q then qd).
STATE_MAP = np.array([[0, 2], [1, 3]], dtype=np.int64)
#: (R, UNP): the fleet-parameter index of each unit parameter of copy b.
PARAM_MAP = np.array([[0], [0]], dtype=np.int64)
#: (UN,): the unit coordinates each copy owns; the others are shared (every copy computes the same values).
OWN = np.array([True])
#: (R, UM): the fleet-control (and phi) index of each unit control of copy b.
CONTROL_MAP = np.array([[0], [1]], dtype=np.int64)
#: (R, UNAUX): the fleet-output index of each unit output of copy b.
AUX_MAP = np.array([[0], [1]], dtype=np.int64)

# --- unit: end
# isort: split

M = R * UM
NG = R * UNG
NAUX = R * UNAUX


@njit(cache=True)
def _scratch():
    """Unit-sized scratch vectors (one allocation): state, parameters, controls or outputs, a
    derivative or the sizes of the singular test, Y, C by block rows and G."""
    k = max(UM, UNG, UNAUX, 1)
    o1 = 2 * UN
    o2 = o1 + max(UNP, 1)
    o3 = o2 + k
    o4 = o3 + 2 * max(UN, UM)
    o5 = o4 + UN * UM
    o6 = o5 + UM * BLOCK
    flat = np.empty(o6 + UM)
    return (flat[0:o1], flat[o1:o2], flat[o2:o3], flat[o3:o4], flat[o4:o5].reshape((UN, UM)),
            flat[o5:o6].reshape((UM, BLOCK)), flat[o6:o6 + UM])


@njit(cache=True)
def _gather(b, s, p, us, up):
    for i in range(2 * UN):
        us[i] = s[STATE_MAP[b, i]]
    for i in range(UNP):
        up[i] = p[PARAM_MAP[b, i]]


@njit(cache=True, error_model="numpy")
def _accel(s, p, u, ds):
    """ds[N:] = a0(s) + Y(s) u, copy by copy, in place (each copy writes the shared accelerations
    again, with the same values)."""
    for b in range(R):
        _unit_accel_at(s, p, u, ds, STATE_MAP[b], PARAM_MAP[b], CONTROL_MAP[b])


@njit(cache=True, error_model="numpy")
def _phi(s, p, out):
    """out = phi(s): copy b's components at CONTROL_MAP[b]."""
    for b in range(R):
        _unit_phi_at(s, p, out, STATE_MAP[b], PARAM_MAP[b], CONTROL_MAP[b])


@njit(cache=True, error_model="numpy")
def _phi_h(s, p, out):
    """out = phi_h(q) (holonomic constraints)."""
    us, up, uo, _, _, _, _ = _scratch()
    for b in range(R):
        _gather(b, s, p, us, up)
        _unit_phi_h(us, up, uo)
        for a in range(UM):
            out[b * UM + a] = uo[a]


@njit(cache=True, error_model="numpy")
def _aux(s, p, out):
    """The extra outputs: copy b's at AUX_MAP[b]."""
    for b in range(R):
        _unit_aux_at(s, p, out, STATE_MAP[b], PARAM_MAP[b], AUX_MAP[b])


@njit(cache=True, error_model="numpy")
def _cg(s, p, C, G):
    """C (block-diagonal, one block per copy, by block rows) and G(phi)."""
    us, up, _, _, _, uc, ug = _scratch()
    for b in range(R):
        _gather(b, s, p, us, up)
        _unit_cg(us, up, uc, ug)
        for a in range(UM):
            G[b * UM + a] = ug[a]
            for j in range(BLOCK):
                C[b * UM + a, j] = uc[a, j]


@njit(cache=True, error_model="numpy")
def _cgn(s, p, C, G, sizes):
    """C, G(phi) and the squared sizes of the singular test, copy by copy (one gather per copy).

    Copy ``b``'s rows of ``d phi/d qd`` and its input fields involve only its unit's coordinates,
    so their sizes are the unit's: the fleet's measure is the smallest of its copies' measures."""
    us, up, _, ud, _, uc, ug = _scratch()
    for b in range(R):
        _gather(b, s, p, us, up)
        _unit_cg(us, up, uc, ug)
        for a in range(UM):
            G[b * UM + a] = ug[a]
            for j in range(BLOCK):
                C[b * UM + a, j] = uc[a, j]
        _unit_tn(us, up, ud)  # 2 UM sizes, in the 2 UN-long derivative scratch
        for a in range(UM):
            sizes[b * UM + a] = ud[a]
            sizes[M + b * UM + a] = ud[UM + a]


@njit(cache=True, error_model="numpy")
def _dyn(s, p, a0, Y):
    """Drift a0 and input fields Y (copy b's controls move only its own coordinates)."""
    us, up, _, ua0, uy, _, _ = _scratch()
    for i in range(Y.shape[0]):
        for j in range(Y.shape[1]):
            Y[i, j] = 0.0
    for b in range(R):
        _gather(b, s, p, us, up)
        _unit_dyn(us, up, ua0, uy)
        for i in range(UN):
            if OWN[i] or b == 0:
                j = STATE_MAP[b, i]
                a0[j] = ua0[i]
                if OWN[i]:
                    for a in range(UM):
                        Y[j, b * UM + a] = uy[i, a]


@njit(cache=True, error_model="numpy")
def _energy(s, p):
    """Every copy's energy, with the shared part counted once: the sum of the copies' unit energies
    minus ``R - 1`` times copy 0's unit energy with its own coordinates at zero (exact when the
    unit's potential vanishes with them, as gravity's does at zero height; else up to a constant)."""
    us, up, _, _, _, _, _ = _scratch()
    e = 0.0
    for b in range(R):
        _gather(b, s, p, us, up)
        e += _unit_energy(us, up)
    _gather(0, s, p, us, up)
    for i in range(UN):
        if OWN[i]:
            us[i] = 0.0
            us[UN + i] = 0.0
    return e - (R - 1) * _unit_energy(us, up)

