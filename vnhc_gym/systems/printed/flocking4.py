"""The flocking4 system.

Printed from ``vnhc_gym.systems.flocking_system(4)`` by ``python -m vnhc_gym.systems.printed``: do not edit, regenerate.
Every function takes one state ``s`` (``q`` then ``qd``) and one parameter vector ``p``.
"""

import jax.numpy as jnp

NAME = 'flocking4'
N = 8
M = 3
STATE_NAMES = ('x_1', 'x_2', 'x_3', 'x_4', 'z_1', 'z_2', 'z_3', 'z_4', 'xd_1', 'xd_2', 'xd_3', 'xd_4', 'zd_1', 'zd_2', 'zd_3', 'zd_4')
PARAM_NAMES = ('m_1', 'm_2', 'm_3', 'm_4', 'g')
PARAM_DEFAULTS = (2.0, 2.0, 2.0, 2.0, 10.0)
PARAM_POSITIVE = (True, True, True, True, True)
OUTPUT_NAMES = ()
HOLONOMIC = False


def drift(s, p):
    """Drift acceleration ``a0`` (no control), shape ``(n,)``."""
    g = p[4]
    _c0 = -g
    return jnp.reshape(jnp.stack([jnp.full_like(s[0], 0), jnp.full_like(s[0], 0), jnp.full_like(s[0], 0), jnp.full_like(s[0], 0), _c0, _c0, _c0, _c0]), (8,))


def input_fields(s, p):
    """Input fields ``Y`` (column ``a``: the acceleration of unit control ``a``), shape ``(n, m)``."""
    m_1 = p[0]
    m_2 = p[1]
    m_3 = p[2]
    _c0 = m_1**(-1.0)
    _c1 = m_2**(-1.0)
    _c2 = m_3**(-1.0)
    return jnp.reshape(jnp.stack([_c0, jnp.full_like(s[0], 0), jnp.full_like(s[0], 0), jnp.full_like(s[0], 0), _c1, jnp.full_like(s[0], 0), jnp.full_like(s[0], 0), jnp.full_like(s[0], 0), _c2, jnp.full_like(s[0], 0), jnp.full_like(s[0], 0), jnp.full_like(s[0], 0), _c0, jnp.full_like(s[0], 0), jnp.full_like(s[0], 0), jnp.full_like(s[0], 0), _c1, jnp.full_like(s[0], 0), jnp.full_like(s[0], 0), jnp.full_like(s[0], 0), _c2, jnp.full_like(s[0], 0), jnp.full_like(s[0], 0), jnp.full_like(s[0], 0)]), (8, 3))


def phi(s, p):
    """The constraint ``phi`` (``psi`` for a holonomic one), shape ``(m,)``."""
    xd_1 = s[8]
    xd_2 = s[9]
    xd_3 = s[10]
    xd_4 = s[11]
    zd_1 = s[12]
    zd_2 = s[13]
    zd_3 = s[14]
    zd_4 = s[15]
    return jnp.reshape(jnp.stack([-xd_1*zd_4 + xd_4*zd_1, -xd_2*zd_4 + xd_4*zd_2, -xd_3*zd_4 + xd_4*zd_3]), (3,))


def decoupling_matrix(s, p):
    """Decoupling matrix ``C = d phi / d qd . Y``, shape ``(m, m)``."""
    xd_4 = s[11]
    zd_4 = s[15]
    m_1 = p[0]
    m_2 = p[1]
    m_3 = p[2]
    _c0 = xd_4 - zd_4
    return jnp.reshape(jnp.stack([_c0/m_1, jnp.full_like(s[0], 0), jnp.full_like(s[0], 0), jnp.full_like(s[0], 0), _c0/m_2, jnp.full_like(s[0], 0), jnp.full_like(s[0], 0), jnp.full_like(s[0], 0), _c0/m_3]), (3, 3))


def drift_term(s, p):
    """``G``: the rate of ``phi`` along the drift, shape ``(m,)``."""
    xd_1 = s[8]
    xd_2 = s[9]
    xd_3 = s[10]
    xd_4 = s[11]
    g = p[4]
    _c0 = -xd_4
    return jnp.reshape(jnp.stack([g*(_c0 + xd_1), g*(_c0 + xd_2), g*(_c0 + xd_3)]), (3,))


def singular_sizes(s, p):
    """Squared sizes ``|J_b|^2`` then ``|Y^a|^2`` of the factors of ``C = J Y`` (the law's singular test), shape ``(2 m,)``."""
    xd_1 = s[8]
    xd_2 = s[9]
    xd_3 = s[10]
    xd_4 = s[11]
    zd_1 = s[12]
    zd_2 = s[13]
    zd_3 = s[14]
    zd_4 = s[15]
    m_1 = p[0]
    m_2 = p[1]
    m_3 = p[2]
    m_4 = p[3]
    _c0 = m_1**(-1.0)
    _c1 = m_4**(-1.0)
    _c2 = m_4*(xd_4**2 + zd_4**2)
    _c3 = m_2**(-1.0)
    _c4 = m_3**(-1.0)
    return jnp.reshape(jnp.stack([_c0*_c1*(_c2 + m_1*(xd_1**2 + zd_1**2)), _c1*_c3*(_c2 + m_2*(xd_2**2 + zd_2**2)), _c1*_c4*(_c2 + m_3*(xd_3**2 + zd_3**2)), 2*_c0, 2*_c3, 2*_c4]), (6,))


def energy(s, p):
    """Mechanical energy, a scalar."""
    z_1 = s[4]
    z_2 = s[5]
    z_3 = s[6]
    z_4 = s[7]
    xd_1 = s[8]
    xd_2 = s[9]
    xd_3 = s[10]
    xd_4 = s[11]
    zd_1 = s[12]
    zd_2 = s[13]
    zd_3 = s[14]
    zd_4 = s[15]
    m_1 = p[0]
    m_2 = p[1]
    m_3 = p[2]
    m_4 = p[3]
    g = p[4]
    _c0 = (1/2)*m_1
    _c1 = (1/2)*m_2
    _c2 = (1/2)*m_3
    _c3 = (1/2)*m_4
    return jnp.reshape(jnp.stack([_c0*xd_1**2 + _c0*zd_1**2 + _c1*xd_2**2 + _c1*zd_2**2 + _c2*xd_3**2 + _c2*zd_3**2 + _c3*xd_4**2 + _c3*zd_4**2 + g*m_1*z_1 + g*m_2*z_2 + g*m_3*z_3 + g*m_4*z_4]), ())
