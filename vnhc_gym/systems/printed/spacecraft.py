"""The spacecraft system.

Printed from ``vnhc_gym.systems.spacecraft_system()`` by ``python -m vnhc_gym.systems.printed``: do not edit, regenerate.
Every function takes one state ``s`` (``q`` then ``qd``) and one parameter vector ``p``.
"""

import jax.numpy as jnp

NAME = 'spacecraft'
N = 3
M = 3
STATE_NAMES = ('psi', 'theta', 'varphi', 'psid', 'thetad', 'varphid')
PARAM_NAMES = ('J1', 'J2', 'J3', 'Omega', 'lam')
PARAM_DEFAULTS = (1.0, 1.5, 2.0, 1.0, 1.0)
PARAM_POSITIVE = (True, True, True, False, True)
OUTPUT_NAMES = ()
HOLONOMIC = False


def drift(s, p):
    """Drift acceleration ``a0`` (no control), shape ``(n,)``."""
    theta = s[1]
    varphi = s[2]
    psid = s[3]
    thetad = s[4]
    varphid = s[5]
    J1 = p[0]
    J2 = p[1]
    J3 = p[2]
    _c0 = 4*thetad
    _c1 = jnp.cos(theta)
    _c2 = _c1*psid
    _c3 = J1*_c2
    _c4 = _c0*_c3
    _c5 = 2*varphi
    _c6 = thetad*jnp.sin(_c5)
    _c7 = jnp.cos(_c5)
    _c8 = _c1*_c7
    _c9 = -_c6 + _c8*psid
    _c10 = J2 - J3
    _c11 = _c10*thetad
    _c12 = 2*_c11
    _c13 = -_c5 + theta
    _c14 = _c5 + theta
    _c15 = jnp.sin(_c13) - jnp.sin(_c14)
    _c16 = _c15*psid - 2*_c7*thetad
    _c17 = _c10*_c2
    _c18 = _c12*_c9 - _c16*_c17 + _c4
    _c19 = jnp.sin(theta)
    _c20 = jnp.cos(varphi)
    _c21 = _c20**2
    _c22 = jnp.sin(varphi)
    _c23 = _c22**2
    _c24 = J3*_c23
    _c25 = 2*J2*_c21 + 2*_c24
    _c26 = 4*varphid
    _c27 = J1*_c1*_c26*thetad
    _c28 = _c26*_c8
    _c29 = jnp.cos(_c13)
    _c30 = jnp.cos(_c14)
    _c31 = thetad*(_c29 - _c30)
    _c32 = J2*_c23
    _c33 = J3*_c21 + _c32
    _c34 = _c0*_c19*(-J1 + _c33)
    _c35 = _c10*varphid
    _c36 = 2*_c2
    _c37 = _c25*(_c11*(-_c28 + _c31) + _c27 + _c36*(_c15*_c35 + _c34))
    _c38 = 8*varphid
    _c39 = _c38*_c6
    _c40 = psid**2
    _c41 = jnp.sin(2*theta)
    _c42 = J2*_c40
    _c43 = 2*_c41
    _c44 = J3*_c40
    _c45 = jnp.sin(2*theta + 2*varphi)
    _c46 = _c26*psid
    _c47 = J2*_c46
    _c48 = J3*_c46
    _c49 = jnp.sin(2*theta - 2*varphi)
    _c50 = _c1*(-4*J1*_c40*_c41 - J2*_c39 + J3*_c39 + _c29*_c47 - _c29*_c48 + _c3*_c38 + _c30*_c47 - _c30*_c48 + _c42*_c43 - _c42*_c45 - _c42*_c49 + _c43*_c44 + _c44*_c45 + _c44*_c49)
    _c51 = _c10*_c20*_c22
    _c52 = _c50*_c51
    _c53 = (1/8)/(J2*J3)
    _c54 = _c53/_c1**2
    _c55 = 2*_c51
    _c56 = J1*_c19
    _c57 = J2*J3
    _c58 = _c19**2
    _c59 = J1*_c58
    return jnp.reshape(jnp.stack([_c54*(_c18*_c19*_c25 + _c37 + _c52), -_c53*(_c19*_c55*(_c12*_c9 - _c16*_c17 + _c4) + _c33*_c50 + _c55*(_c27 + _c36*(_c15*_c35 + _c34) + thetad*(-_c10*_c28 + _c10*_c31)))/_c1, _c54*(2*_c18*(J2*_c59 + _c24*_c59 - _c32*_c59 - _c57*_c58 + _c57) + _c37*_c56 + _c52*_c56)/J1]), (3,))


def input_fields(s, p):
    """Input fields ``Y`` (column ``a``: the acceleration of unit control ``a``), shape ``(n, m)``."""
    theta = s[1]
    varphi = s[2]
    J1 = p[0]
    J2 = p[1]
    J3 = p[2]
    _c0 = jnp.cos(theta)**(-1.0)
    _c1 = J2**(-1.0)
    _c2 = jnp.sin(varphi)
    _c3 = _c1*_c2
    _c4 = jnp.cos(varphi)
    _c5 = J3**(-1.0)
    _c6 = _c4*_c5
    _c7 = jnp.tan(theta)
    return jnp.reshape(jnp.stack([jnp.full_like(s[0], 0), _c0*_c3, _c0*_c6, jnp.full_like(s[0], 0), _c1*_c4, -_c2*_c5, J1**(-1.0), _c3*_c7, _c6*_c7]), (3, 3))


def phi(s, p):
    """The constraint ``phi`` (``psi`` for a holonomic one), shape ``(m,)``."""
    theta = s[1]
    varphi = s[2]
    psid = s[3]
    thetad = s[4]
    varphid = s[5]
    Omega = p[3]
    lam = p[4]
    _c0 = jnp.sin(theta)
    _c1 = jnp.sin(varphi)
    _c2 = jnp.cos(theta)
    _c3 = _c1*_c2
    _c4 = jnp.cos(varphi)
    return jnp.reshape(jnp.stack([-_c0*psid + _c3*lam + varphid, _c0*lam + _c3*psid + _c4*thetad, -Omega - _c1*thetad + _c2*_c4*psid]), (3,))


def decoupling_matrix(s, p):
    """Decoupling matrix ``C = d phi / d qd . Y``, shape ``(m, m)``."""
    theta = s[1]
    varphi = s[2]
    J1 = p[0]
    J2 = p[1]
    J3 = p[2]
    _c0 = jnp.sin(varphi)
    _c1 = J2**(-1.0)
    _c2 = -jnp.sin(theta)/jnp.cos(theta) + jnp.tan(theta)
    _c3 = jnp.cos(varphi)
    _c4 = J3**(-1.0)
    _c5 = _c0**2 + _c3**2
    return jnp.reshape(jnp.stack([J1**(-1.0), _c0*_c1*_c2, _c2*_c3*_c4, jnp.full_like(s[0], 0), _c1*_c5, jnp.full_like(s[0], 0), jnp.full_like(s[0], 0), jnp.full_like(s[0], 0), _c4*_c5]), (3, 3))


def drift_term(s, p):
    """``G``: the rate of ``phi`` along the drift, shape ``(m,)``."""
    theta = s[1]
    varphi = s[2]
    psid = s[3]
    thetad = s[4]
    varphid = s[5]
    J1 = p[0]
    J2 = p[1]
    J3 = p[2]
    lam = p[4]
    _c0 = jnp.cos(varphi)
    _c1 = jnp.cos(theta)
    _c2 = _c1*lam
    _c3 = _c1*psid
    _c4 = jnp.sin(varphi)
    _c5 = jnp.sin(theta)
    _c6 = _c4*_c5
    _c7 = 4*thetad
    _c8 = J1*_c3
    _c9 = _c7*_c8
    _c10 = 2*varphi
    _c11 = thetad*jnp.sin(_c10)
    _c12 = jnp.cos(_c10)
    _c13 = -_c11 + _c12*_c3
    _c14 = J2 - J3
    _c15 = _c14*thetad
    _c16 = 2*_c15
    _c17 = -_c10 + theta
    _c18 = _c10 + theta
    _c19 = jnp.sin(_c17) - jnp.sin(_c18)
    _c20 = -2*_c12*thetad + _c19*psid
    _c21 = _c14*_c3
    _c22 = _c13*_c16 - _c20*_c21 + _c9
    _c23 = _c0**2
    _c24 = _c4**2
    _c25 = J3*_c24
    _c26 = 2*J2*_c23 + 2*_c25
    _c27 = _c26*_c5
    _c28 = 4*varphid
    _c29 = _c1*_c28
    _c30 = J1*_c29*thetad
    _c31 = _c12*_c29
    _c32 = jnp.cos(_c17)
    _c33 = jnp.cos(_c18)
    _c34 = thetad*(_c32 - _c33)
    _c35 = J2*_c24
    _c36 = J3*_c23 + _c35
    _c37 = _c5*_c7*(-J1 + _c36)
    _c38 = _c14*varphid
    _c39 = 2*_c3
    _c40 = _c26*(_c15*(-_c31 + _c34) + _c30 + _c39*(_c19*_c38 + _c37))
    _c41 = 8*varphid
    _c42 = _c11*_c41
    _c43 = psid**2
    _c44 = jnp.sin(2*theta)
    _c45 = J2*_c43
    _c46 = 2*_c44
    _c47 = J3*_c43
    _c48 = jnp.sin(2*theta + 2*varphi)
    _c49 = _c28*psid
    _c50 = J2*_c49
    _c51 = J3*_c49
    _c52 = jnp.sin(2*theta - 2*varphi)
    _c53 = _c1*(-4*J1*_c43*_c44 - J2*_c42 + J3*_c42 + _c32*_c50 - _c32*_c51 + _c33*_c50 - _c33*_c51 + _c41*_c8 + _c45*_c46 - _c45*_c48 - _c45*_c52 + _c46*_c47 + _c47*_c48 + _c47*_c52)
    _c54 = _c0*_c14
    _c55 = _c4*_c54
    _c56 = _c40 + _c53*_c55
    _c57 = _c22*_c27 + _c56
    _c58 = J2**(-1.0)
    _c59 = J3**(-1.0)
    _c60 = (1/8)*_c58*_c59
    _c61 = _c60/_c1**2
    _c62 = J2*J3
    _c63 = _c5**2
    _c64 = J1*_c63
    _c65 = _c54*_c6
    _c66 = _c1**(-1.0)
    _c67 = _c60*_c66
    _c68 = _c13*_c16 - _c20*_c21 + _c9
    _c69 = _c36*_c53 + 2*_c55*(_c30 + _c39*(_c19*_c38 + _c37) + thetad*(-_c14*_c31 + _c14*_c34)) + 2*_c65*_c68
    _c70 = _c0*thetad
    return jnp.reshape(jnp.stack([_c0*_c2*varphid - _c5*_c57*_c61 - thetad*(_c3 + _c6*lam) + _c61*(J1*_c40*_c5 + J1*_c53*_c65 + 2*_c22*(J2*_c64 + _c25*_c64 - _c35*_c64 - _c62*_c63 + _c62))/J1, -_c0*_c67*_c69 + _c4*_c57*_c67 + thetad*(_c2 - _c6*psid) + varphid*(_c0*_c3 - _c4*thetad), (1/8)*_c0*_c58*_c59*_c66*(_c27*_c68 + _c56) + (1/8)*_c4*_c58*_c59*_c66*_c69 - _c5*_c70*psid - varphid*(_c3*_c4 + _c70)]), (3,))


def singular_sizes(s, p):
    """Squared sizes ``|J_b|^2`` then ``|Y^a|^2`` of the factors of ``C = J Y`` (the law's singular test), shape ``(2 m,)``."""
    J1 = p[0]
    J2 = p[1]
    J3 = p[2]
    _c0 = J1**(-1.0)
    _c1 = J2**(-1.0)
    _c2 = J3**(-1.0)
    return jnp.reshape(jnp.stack([_c0, _c1, _c2, _c0, _c1, _c2]), (6,))


def energy(s, p):
    """Mechanical energy, a scalar."""
    theta = s[1]
    varphi = s[2]
    psid = s[3]
    thetad = s[4]
    varphid = s[5]
    J1 = p[0]
    J2 = p[1]
    J3 = p[2]
    _c0 = jnp.sin(theta)
    _c1 = J1*varphid
    _c2 = jnp.cos(theta)
    _c3 = jnp.cos(varphi)
    _c4 = jnp.sin(varphi)
    _c5 = _c2*_c3*_c4*(J2 - J3)
    _c6 = _c3**2
    _c7 = _c4**2
    _c8 = _c2**2
    return jnp.reshape(jnp.stack([-1/2*_c1*(_c0*psid - varphid) + (1/2)*psid*(-_c0*_c1 + _c5*thetad + psid*(J1*_c0**2 + J2*_c7*_c8 + J3*_c6*_c8)) + (1/2)*thetad*(_c5*psid + thetad*(J2*_c6 + J3*_c7))]), ())
