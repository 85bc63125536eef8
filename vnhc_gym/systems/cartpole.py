"""A pole on a cart, pushed by one horizontal force and held upright by a velocity constraint.

``q = (x, theta)``: the cart's position and the pole's angle from the upright (``theta = 0`` up,
``theta > 0`` leaning towards ``+x``).  The pole is a uniform rod of mass ``m_p`` whose centre
of mass sits at ``l`` (its half-length) from the pivot, so its inertia about the centre of mass is
``m_p l^2 / 3`` and ``J = 4/3 m_p l^2`` about the pivot.  The cart has mass ``M_c``, viscous
friction ``b_c`` on the track and the force ``u`` (covector ``dx``); gravity ``g`` acts on the
pole through ``V = m_p g l cos(theta)``.  The kinetic energy

.. math::

    T = \\tfrac12 (M_c + m_p)\\,\\dot x^2 + m_p l \\cos\\theta\\,\\dot x\\dot\\theta
        + \\tfrac12 J \\dot\\theta^2

gives the equations of motion

.. math::

    (M_c + m_p)\\,\\ddot x + m_p l\\cos\\theta\\,\\ddot\\theta - m_p l \\sin\\theta\\,\\dot\\theta^2
        = u - b_c \\dot x, \\qquad
    \\cos\\theta\\,\\ddot x + \\ell\\,\\ddot\\theta - g\\sin\\theta = 0,

with ``ell = J / (m_p l) = 4 l / 3`` the length of the equivalent simple pendulum.  The force
enters the cart's equation only: two coordinates, one input.

The virtual constraint, with gains ``lam > 0``, ``mu >= 0``, ``nu >= 0``,

.. math::

    \\phi = \\dot\\theta + \\lambda \\sin\\theta + \\mu\\,\\dot x + \\nu\\,x \\qquad (\\mathrm{rad/s}),

asks the pole to turn towards the upright at the rate ``lam sin(theta)``, corrected by the
cart's speed and position.

Decoupling matrix.  ``d phi/d qd = (mu, 1)`` and ``Y = M^-1 dx = (J, -m_p l cos theta) / det M``
give the scalar

.. math::

    C = \\frac{\\mu\\,\\ell - \\cos\\theta}{l\\,\\big(\\tfrac43 (M_c + m_p) - m_p\\cos^2\\theta\\big)} .

The law is singular where ``cos(theta) = mu ell``: at ``theta = +-pi/2`` (the pole horizontal)
when ``mu = 0``, and already at ``|theta| = arccos(mu ell)`` (1.37 rad with the defaults)
otherwise.  There the force cannot change ``phi``: the angular acceleration a push gives the
pole cancels ``mu`` times the acceleration it gives the cart.

Reduced dynamics on ``phi = 0``.  The pole's equation has no input, so on the manifold it fixes
the cart's acceleration; with ``v = xd``,

.. math::

    \\dot x = v, \\qquad
    \\dot\\theta = -\\lambda\\sin\\theta - \\mu v - \\nu x, \\qquad
    (\\cos\\theta - \\mu\\ell)\\,\\dot v = g\\sin\\theta + \\ell\\lambda\\cos\\theta\\,\\dot\\theta + \\ell\\nu v,

in which neither ``M_c`` nor ``b_c`` appears (the force absorbs them).  With ``mu = nu = 0`` they
solve in closed form: ``tan(theta/2) = tan(theta_0/2) exp(-lam t)`` and
``v = v_0 + (g / lam)(artanh sin theta_0 - artanh sin theta) - ell lam (theta_0 - theta)``, so
the pole rises but the cart keeps the generically nonzero speed
``v_0 + (g / lam) artanh(sin theta_0) - ell lam theta_0`` and runs away.  The ``mu`` and ``nu``
terms stop it: linearised at the upright, ``(x, theta, v)`` has the characteristic polynomial

.. math::

    s^3 + \\frac{\\lambda - \\ell\\nu}{D}\\,s^2 + \\frac{\\mu g}{D}\\,s + \\frac{\\nu g}{D},
    \\qquad D = 1 - \\mu\\ell,

which is Hurwitz exactly when ``0 < mu ell < 1`` and ``0 < nu < lam mu`` (Routh-Hurwitz):
then the pole comes upright and the cart back to rest at ``x = 0``.  With ``nu = 0`` a root sits
at 0: the cart comes to rest, somewhere.  The defaults ``lam = 2``, ``mu = 0.3``, ``nu = 0.2``
(with ``ell = 2/3 m``) place the roots at ``-1.05`` and ``-0.64 +- 1.39 i`` (1/s).
"""

from __future__ import annotations

from functools import cache
from typing import TYPE_CHECKING

from vnhc_gym.mechanics import ConstrainedSystem
from vnhc_gym.systems.printed import printed_module

if TYPE_CHECKING:
    from vnhc_gym.mechanics import MechanicalSystem, VelocityConstraint

__all__ = ["cartpole_system", "make_cartpole"]


def cartpole_system() -> tuple[MechanicalSystem, VelocityConstraint]:
    """The symbolic cart-pole and its upright constraint ``thetad + lam sin(theta) + mu xd + nu x``.

    Returns
    -------
    (MechanicalSystem, VelocityConstraint)
        Parameters, in order: ``M_c`` (kg), ``m_p`` (kg), ``l`` (m), ``g`` (m/s^2), ``b_c``
        (N s/m), ``lam`` (1/s), ``mu`` (rad/m), ``nu`` (rad/(m s)).  ``b_c``, ``mu`` and ``nu`` may
        be 0 (no friction; the constraint without its cart terms), so they are declared
        non-negative rather than positive; the core then checks only that they are finite.
    """
    import sympy as sp

    from vnhc_gym.mechanics import MechanicalSystem, VelocityConstraint

    x, th = sp.symbols("x theta", real=True)
    xd, thd = sp.symbols("xd thetad", real=True)
    m_cart, m_pole, length, grav, lam = sp.symbols("M_c m_p l g lam", positive=True)
    friction, mu, nu = sp.symbols("b_c mu nu", nonnegative=True)
    s, c = sp.sin(th), sp.cos(th)
    # Uniform rod: m l^2 / 3 about the centre of mass plus m l^2 to carry it to the pivot.
    pivot_inertia = sp.Rational(4, 3) * m_pole * length**2
    mass = sp.Matrix([[m_cart + m_pole, m_pole * length * c], [m_pole * length * c, pivot_inertia]])
    system = MechanicalSystem(
        name="cartpole", q=(x, th), qd=(xd, thd), mass_matrix=mass,
        control_forces=sp.Matrix([[1], [0]]),
        potential=m_pole * grav * length * c,
        external_force=sp.Matrix([-friction * xd, 0]),
        params={m_cart: 1.0, m_pole: 0.2, length: 0.5, grav: 9.81, friction: 0.1, lam: 2.0, mu: 0.3, nu: 0.2},
    )
    phi = sp.Matrix([thd + lam * s + mu * xd + nu * x])
    return system, VelocityConstraint(phi)


@cache
def make_cartpole() -> ConstrainedSystem:
    """The compiled cart-pole; parameters ``(M_c, m_p, l, g, b_c, lam, mu, nu)``, defaults
    ``(1, 0.2, 0.5, 9.81, 0.1, 2, 0.3, 0.2)``."""
    return ConstrainedSystem.from_recipe(("cartpole",), cartpole_system, printed=printed_module("cartpole"))
