"""The sled system.

Printed from ``vnhc_gym.systems.sled_system()`` by ``python -m vnhc_gym.systems.printed``: do not edit, regenerate.
Every function takes one state ``s`` (``q`` then ``qd``) and one parameter vector ``p``.
"""

import jax.numpy as jnp

NAME = 'sled'
N = 3
M = 2
STATE_NAMES = ('x', 'y', 'theta', 'xd', 'yd', 'thetad')
PARAM_NAMES = ('m', 'I', 'a', 'v_ref')
PARAM_DEFAULTS = (20.0, 2.0, 0.3, 1.5)
PARAM_POSITIVE = (True, True, True, True)
OUTPUT_NAMES = ()
HOLONOMIC = False


def drift(s, p):
    """Drift acceleration ``a0`` (no control), shape ``(n,)``."""
    theta = s[2]
    thetad = s[5]
    a = p[2]
    _c0 = a*thetad**2
    return jnp.reshape(jnp.stack([_c0*jnp.cos(theta), _c0*jnp.sin(theta), jnp.full_like(s[0], 0)]), (3,))


def input_fields(s, p):
    """Input fields ``Y`` (column ``a``: the acceleration of unit control ``a``), shape ``(n, m)``."""
    theta = s[2]
    m = p[0]
    I = p[1]
    a = p[2]
    _c0 = jnp.cos(theta)
    _c1 = m**(-1.0)
    _c2 = jnp.sin(theta)
    _c3 = I**(-1.0)
    _c4 = _c3*a
    return jnp.reshape(jnp.stack([_c0*_c1, _c2*_c4, _c1*_c2, -_c0*_c4, jnp.full_like(s[0], 0), _c3]), (3, 2))


def phi(s, p):
    """The constraint ``phi`` (``psi`` for a holonomic one), shape ``(m,)``."""
    theta = s[2]
    xd = s[3]
    yd = s[4]
    v_ref = p[3]
    _c0 = jnp.sin(theta)
    _c1 = jnp.cos(theta)
    return jnp.reshape(jnp.stack([-_c0*xd + _c1*yd, _c0*yd + _c1*xd - v_ref]), (2,))


def decoupling_matrix(s, p):
    """Decoupling matrix ``C = d phi / d qd . Y``, shape ``(m, m)``."""
    theta = s[2]
    m = p[0]
    I = p[1]
    a = p[2]
    _c0 = jnp.sin(theta)**2 + jnp.cos(theta)**2
    return jnp.reshape(jnp.stack([jnp.full_like(s[0], 0), -_c0*a/I, _c0/m, jnp.full_like(s[0], 0)]), (2, 2))


def drift_term(s, p):
    """``G``: the rate of ``phi`` along the drift, shape ``(m,)``."""
    theta = s[2]
    xd = s[3]
    yd = s[4]
    thetad = s[5]
    a = p[2]
    _c0 = jnp.cos(theta)
    _c1 = jnp.sin(theta)
    _c2 = a*thetad
    return jnp.reshape(jnp.stack([-thetad*(_c0*xd + _c1*yd), thetad*(_c0**2*_c2 + _c0*yd + _c1**2*_c2 - _c1*xd)]), (2,))


def singular_sizes(s, p):
    """Squared sizes ``|J_b|^2`` then ``|Y^a|^2`` of the factors of ``C = J Y`` (the law's singular test), shape ``(2 m,)``."""
    m = p[0]
    I = p[1]
    a = p[2]
    _c0 = m**(-1.0)
    _c1 = I**(-1.0)
    return jnp.reshape(jnp.stack([_c0 + _c1*a**2, _c0, _c0, _c1]), (4,))


def energy(s, p):
    """Mechanical energy, a scalar."""
    theta = s[2]
    xd = s[3]
    yd = s[4]
    thetad = s[5]
    m = p[0]
    I = p[1]
    a = p[2]
    _c0 = jnp.cos(theta)
    _c1 = a*thetad
    _c2 = m*yd
    _c3 = jnp.sin(theta)
    _c4 = m*xd
    return jnp.reshape(jnp.stack([(1/2)*_c2*(_c0*_c1 + yd) - 1/2*_c4*(_c1*_c3 - xd) + (1/2)*thetad*(_c0*_c2*a - _c3*_c4*a + thetad*(I + a**2*m))]), ())
