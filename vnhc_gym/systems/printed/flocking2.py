"""The flocking2 system.

Printed from ``vnhc_gym.systems.flocking_system(2)`` by ``python -m vnhc_gym.systems.printed``: do not edit, regenerate.
Every function takes one state ``s`` (``q`` then ``qd``) and one parameter vector ``p``.
"""

import jax.numpy as jnp

NAME = 'flocking2'
N = 4
M = 1
STATE_NAMES = ('x_1', 'x_2', 'z_1', 'z_2', 'xd_1', 'xd_2', 'zd_1', 'zd_2')
PARAM_NAMES = ('m_1', 'm_2', 'g')
PARAM_DEFAULTS = (2.0, 2.0, 10.0)
PARAM_POSITIVE = (True, True, True)
OUTPUT_NAMES = ()
HOLONOMIC = False


def drift(s, p):
    """Drift acceleration ``a0`` (no control), shape ``(n,)``."""
    g = p[2]
    _c0 = -g
    return jnp.reshape(jnp.stack([jnp.full_like(s[0], 0), jnp.full_like(s[0], 0), _c0, _c0]), (4,))


def input_fields(s, p):
    """Input fields ``Y`` (column ``a``: the acceleration of unit control ``a``), shape ``(n, m)``."""
    m_1 = p[0]
    _c0 = m_1**(-1.0)
    return jnp.reshape(jnp.stack([_c0, jnp.full_like(s[0], 0), _c0, jnp.full_like(s[0], 0)]), (4, 1))


def phi(s, p):
    """The constraint ``phi`` (``psi`` for a holonomic one), shape ``(m,)``."""
    xd_1 = s[4]
    xd_2 = s[5]
    zd_1 = s[6]
    zd_2 = s[7]
    return jnp.reshape(jnp.stack([-xd_1*zd_2 + xd_2*zd_1]), (1,))


def decoupling_matrix(s, p):
    """Decoupling matrix ``C = d phi / d qd . Y``, shape ``(m, m)``."""
    xd_2 = s[5]
    zd_2 = s[7]
    m_1 = p[0]
    return jnp.reshape(jnp.stack([(xd_2 - zd_2)/m_1]), (1, 1))


def drift_term(s, p):
    """``G``: the rate of ``phi`` along the drift, shape ``(m,)``."""
    xd_1 = s[4]
    xd_2 = s[5]
    g = p[2]
    return jnp.reshape(jnp.stack([g*(xd_1 - xd_2)]), (1,))


def singular_sizes(s, p):
    """Squared sizes ``|J_b|^2`` then ``|Y^a|^2`` of the factors of ``C = J Y`` (the law's singular test), shape ``(2 m,)``."""
    xd_1 = s[4]
    xd_2 = s[5]
    zd_1 = s[6]
    zd_2 = s[7]
    m_1 = p[0]
    m_2 = p[1]
    _c0 = m_1**(-1.0)
    return jnp.reshape(jnp.stack([_c0*(m_1*(xd_1**2 + zd_1**2) + m_2*(xd_2**2 + zd_2**2))/m_2, 2*_c0]), (2,))


def energy(s, p):
    """Mechanical energy, a scalar."""
    z_1 = s[2]
    z_2 = s[3]
    xd_1 = s[4]
    xd_2 = s[5]
    zd_1 = s[6]
    zd_2 = s[7]
    m_1 = p[0]
    m_2 = p[1]
    g = p[2]
    _c0 = (1/2)*m_1
    _c1 = (1/2)*m_2
    return jnp.reshape(jnp.stack([_c0*xd_1**2 + _c0*zd_1**2 + _c1*xd_2**2 + _c1*zd_2**2 + g*m_1*z_1 + g*m_2*z_2]), ())
