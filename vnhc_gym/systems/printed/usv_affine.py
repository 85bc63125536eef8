"""The usv_affine system.

Printed from ``vnhc_gym.systems.usv_system('affine')`` by ``python -m vnhc_gym.systems.printed``: do not edit, regenerate.
Every function takes one state ``s`` (``q`` then ``qd``) and one parameter vector ``p``.
"""

import jax.numpy as jnp

NAME = 'usv_affine'
N = 3
M = 1
STATE_NAMES = ('x', 'y', 'theta', 'xd', 'yd', 'thetad')
PARAM_NAMES = ('m', 'I', 'current_scale', 'c_c1', 'c_c2', 'c_j11', 'c_j12', 'c_j21', 'c_j22')
PARAM_DEFAULTS = (10.0, 1.5, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
PARAM_POSITIVE = (True, True, True, False, False, False, False, False, False)
OUTPUT_NAMES = ('C1', 'C2', 'dC1dx', 'dC1dy', 'dC2dx', 'dC2dy')
HOLONOMIC = False


def drift(s, p):
    """Drift acceleration ``a0`` (no control), shape ``(n,)``."""
    x = s[0]
    y = s[1]
    theta = s[2]
    xd = s[3]
    yd = s[4]
    thetad = s[5]
    current_scale = p[2]
    c_c1 = p[3]
    c_c2 = p[4]
    c_j11 = p[5]
    c_j12 = p[6]
    c_j21 = p[7]
    c_j22 = p[8]
    _c0 = jnp.sin(theta)
    _c1 = jnp.cos(theta)
    _c2 = xd*(_c0*c_j11 - _c1*c_j21)
    _c3 = yd*(_c0*c_j12 - _c1*c_j22)
    _c4 = _c0**2
    _c5 = c_c2 + c_j21*x + c_j22*y
    _c6 = _c1**2
    _c7 = c_c1 + c_j11*x + c_j12*y
    _c8 = 2*_c0*_c1
    return jnp.reshape(jnp.stack([current_scale*(_c0*_c2 + _c0*_c3 + thetad*(_c4*_c5 - _c5*_c6 + _c7*_c8)), -current_scale*(_c1*_c2 + _c1*_c3 + thetad*(-_c4*_c7 + _c5*_c8 + _c6*_c7)), jnp.full_like(s[0], 0)]), (3,))


def input_fields(s, p):
    """Input fields ``Y`` (column ``a``: the acceleration of unit control ``a``), shape ``(n, m)``."""
    theta = s[2]
    m = p[0]
    I = p[1]
    _c0 = m**(-1.0)
    return jnp.reshape(jnp.stack([_c0*jnp.sin(theta), -_c0*jnp.cos(theta), I**(-1.0)]), (3, 1))


def phi(s, p):
    """The constraint ``phi`` (``psi`` for a holonomic one), shape ``(m,)``."""
    x = s[0]
    y = s[1]
    theta = s[2]
    xd = s[3]
    yd = s[4]
    current_scale = p[2]
    c_c1 = p[3]
    c_c2 = p[4]
    c_j11 = p[5]
    c_j12 = p[6]
    c_j21 = p[7]
    c_j22 = p[8]
    _c0 = jnp.cos(theta)
    _c1 = jnp.sin(theta)
    return jnp.reshape(jnp.stack([_c0*current_scale*(c_c2 + c_j21*x + c_j22*y) - _c0*yd - _c1*current_scale*(c_c1 + c_j11*x + c_j12*y) + _c1*xd]), (1,))


def decoupling_matrix(s, p):
    """Decoupling matrix ``C = d phi / d qd . Y``, shape ``(m, m)``."""
    theta = s[2]
    m = p[0]
    return jnp.reshape(jnp.stack([(jnp.sin(theta)**2 + jnp.cos(theta)**2)/m]), (1, 1))


def drift_term(s, p):
    """``G``: the rate of ``phi`` along the drift, shape ``(m,)``."""
    x = s[0]
    y = s[1]
    theta = s[2]
    xd = s[3]
    yd = s[4]
    thetad = s[5]
    current_scale = p[2]
    c_c1 = p[3]
    c_c2 = p[4]
    c_j11 = p[5]
    c_j12 = p[6]
    c_j21 = p[7]
    c_j22 = p[8]
    _c0 = jnp.sin(theta)
    _c1 = jnp.cos(theta)
    _c2 = _c0*c_j11 - _c1*c_j21
    _c3 = _c2*xd
    _c4 = _c0*c_j12 - _c1*c_j22
    _c5 = _c4*yd
    _c6 = _c1*xd
    _c7 = _c0*yd
    _c8 = c_c1 + c_j11*x + c_j12*y
    _c9 = c_c2 + c_j21*x + c_j22*y
    _c10 = _c1**2
    _c11 = _c0**2
    _c12 = 2*_c0*_c1
    return jnp.reshape(jnp.stack([_c0*current_scale*(_c0*_c3 + _c4*_c7 + thetad*(-_c10*_c9 + _c11*_c9 + _c12*_c8)) + _c1*current_scale*(_c1*_c5 + _c2*_c6 + thetad*(_c10*_c8 - _c11*_c8 + _c12*_c9)) - _c3*current_scale - _c5*current_scale - thetad*(_c0*_c9*current_scale + _c1*_c8*current_scale - _c6 - _c7)]), (1,))


def singular_sizes(s, p):
    """Squared sizes ``|J_b|^2`` then ``|Y^a|^2`` of the factors of ``C = J Y`` (the law's singular test), shape ``(2 m,)``."""
    m = p[0]
    I = p[1]
    _c0 = m**(-1.0)
    return jnp.reshape(jnp.stack([_c0, _c0*(I + m)/I]), (2,))


def energy(s, p):
    """Mechanical energy, a scalar."""
    xd = s[3]
    yd = s[4]
    thetad = s[5]
    m = p[0]
    I = p[1]
    return jnp.reshape(jnp.stack([(1/2)*I*thetad**2 + (1/2)*m*xd**2 + (1/2)*m*yd**2]), ())


def outputs(s, p):
    """Extra outputs ('C1', 'C2', 'dC1dx', 'dC1dy', 'dC2dx', 'dC2dy'), shape ``(6,)``."""
    x = s[0]
    y = s[1]
    current_scale = p[2]
    c_c1 = p[3]
    c_c2 = p[4]
    c_j11 = p[5]
    c_j12 = p[6]
    c_j21 = p[7]
    c_j22 = p[8]
    return jnp.reshape(jnp.stack([current_scale*(c_c1 + c_j11*x + c_j12*y), current_scale*(c_c2 + c_j21*x + c_j22*y), c_j11*current_scale, c_j12*current_scale, c_j21*current_scale, c_j22*current_scale]), (6,))
