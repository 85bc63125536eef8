"""The cartpole system.

Printed from ``vnhc_gym.systems.cartpole_system()`` by ``python -m vnhc_gym.systems.printed``: do not edit, regenerate.
Every function takes one state ``s`` (``q`` then ``qd``) and one parameter vector ``p``.
"""

import jax.numpy as jnp

NAME = 'cartpole'
N = 2
M = 1
STATE_NAMES = ('x', 'theta', 'xd', 'thetad')
PARAM_NAMES = ('M_c', 'm_p', 'l', 'g', 'b_c', 'lam', 'mu', 'nu')
PARAM_DEFAULTS = (1.0, 0.2, 0.5, 9.81, 0.1, 2.0, 0.3, 0.2)
PARAM_POSITIVE = (True, True, True, True, False, True, False, False)
OUTPUT_NAMES = ()
HOLONOMIC = False


def drift(s, p):
    """Drift acceleration ``a0`` (no control), shape ``(n,)``."""
    theta = s[1]
    xd = s[2]
    thetad = s[3]
    M_c = p[0]
    m_p = p[1]
    l = p[2]
    g = p[3]
    b_c = p[4]
    _c0 = jnp.sin(theta)
    _c1 = (4*M_c + 3*_c0**2*m_p + m_p)**(-1.0)
    _c2 = b_c*xd
    _c3 = _c0*l*m_p*thetad**2
    return jnp.reshape(jnp.stack([-_c1*(4*_c2 - 4*_c3 + (3/2)*g*m_p*jnp.sin(2*theta)), 3*_c1*(_c0*g*(M_c + m_p) + (_c2 - _c3)*jnp.cos(theta))/l]), (2,))


def input_fields(s, p):
    """Input fields ``Y`` (column ``a``: the acceleration of unit control ``a``), shape ``(n, m)``."""
    theta = s[1]
    M_c = p[0]
    m_p = p[1]
    l = p[2]
    _c0 = (4*M_c + 3*m_p*jnp.sin(theta)**2 + m_p)**(-1.0)
    return jnp.reshape(jnp.stack([4*_c0, -3*_c0*jnp.cos(theta)/l]), (2, 1))


def phi(s, p):
    """The constraint ``phi`` (``psi`` for a holonomic one), shape ``(m,)``."""
    x = s[0]
    theta = s[1]
    xd = s[2]
    thetad = s[3]
    lam = p[5]
    mu = p[6]
    nu = p[7]
    return jnp.reshape(jnp.stack([lam*jnp.sin(theta) + mu*xd + nu*x + thetad]), (1,))


def decoupling_matrix(s, p):
    """Decoupling matrix ``C = d phi / d qd . Y``, shape ``(m, m)``."""
    theta = s[1]
    M_c = p[0]
    m_p = p[1]
    l = p[2]
    mu = p[6]
    return jnp.reshape(jnp.stack([(4*mu - 3*jnp.cos(theta)/l)/(4*M_c + 3*m_p*jnp.sin(theta)**2 + m_p)]), (1, 1))


def drift_term(s, p):
    """``G``: the rate of ``phi`` along the drift, shape ``(m,)``."""
    theta = s[1]
    xd = s[2]
    thetad = s[3]
    M_c = p[0]
    m_p = p[1]
    l = p[2]
    g = p[3]
    b_c = p[4]
    lam = p[5]
    mu = p[6]
    nu = p[7]
    _c0 = jnp.cos(theta)
    _c1 = jnp.sin(theta)
    _c2 = 3*m_p
    _c3 = (4*M_c + _c1**2*_c2 + m_p)**(-1.0)
    _c4 = b_c*xd
    _c5 = _c1*l*m_p*thetad**2
    return jnp.reshape(jnp.stack([_c0*lam*thetad - 1/2*_c3*mu*(_c2*g*jnp.sin(2*theta) + 8*_c4 - 8*_c5) + 3*_c3*(_c0*(_c4 - _c5) + _c1*g*(M_c + m_p))/l + nu*xd]), (1,))


def singular_sizes(s, p):
    """Squared sizes ``|J_b|^2`` then ``|Y^a|^2`` of the factors of ``C = J Y`` (the law's singular test), shape ``(2 m,)``."""
    theta = s[1]
    M_c = p[0]
    m_p = p[1]
    l = p[2]
    mu = p[6]
    _c0 = l**2
    _c1 = 3*m_p
    _c2 = (4*M_c + _c1*jnp.sin(theta)**2 + m_p)**(-1.0)
    return jnp.reshape(jnp.stack([_c2*(3*M_c + 4*_c0*m_p*mu**2 + _c1 - 6*l*m_p*mu*jnp.cos(theta))/(_c0*m_p), 4*_c2]), (2,))


def energy(s, p):
    """Mechanical energy, a scalar."""
    theta = s[1]
    xd = s[2]
    thetad = s[3]
    M_c = p[0]
    m_p = p[1]
    l = p[2]
    g = p[3]
    _c0 = jnp.cos(theta)
    _c1 = _c0*m_p
    _c2 = l*thetad
    return jnp.reshape(jnp.stack([_c1*g*l + (1/6)*_c2*m_p*(3*_c0*xd + 4*_c2) + (1/2)*xd*(_c1*_c2 + xd*(M_c + m_p))]), ())
