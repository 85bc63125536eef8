"""A knife-edge sled on ice with an offset centre of mass, steered by a thrust and a torque.

``q = (x, y, theta)``: the blade's contact point and the heading.  The centre of mass sits a
distance ``a`` ahead of the blade, so the kinetic energy

.. math::

    T = \\tfrac m2 \\big[(\\dot x - a \\sin\\theta\\,\\dot\\theta)^2 + (\\dot y + a\\cos\\theta\\,\\dot\\theta)^2\\big]
        + \\tfrac I2 \\dot\\theta^2

gives a mass matrix that depends on the heading.  Two controls: a thrust ``u_1`` along the blade
(covector ``cos(theta) dx + sin(theta) dy``) and a torque ``u_2`` (``d theta``).  The virtual
constraint has two components,

.. math::

    \\phi^1 = -\\sin\\theta\\,\\dot x + \\cos\\theta\\,\\dot y, \\qquad
    \\phi^2 = \\cos\\theta\\,\\dot x + \\sin\\theta\\,\\dot y - v_{ref}:

no sideways slip of the blade, and the forward speed at the cruise speed ``v_ref``.  Nothing
physical holds the blade: the controller does.  The decoupling matrix is
``C = [[0, -a/I], [1/m, 0]]`` with ``det C = a / (I m)``: the slip is steered only through the
torque, by way of the offset mass (the law needs ``a != 0``), and the speed only through the thrust.
"""

from __future__ import annotations

from functools import cache
from typing import TYPE_CHECKING

from vnhc_gym.mechanics import ConstrainedSystem
from vnhc_gym.systems.printed import printed_module

if TYPE_CHECKING:
    from vnhc_gym.mechanics import MechanicalSystem, VelocityConstraint

__all__ = ["make_sled", "sled_system"]


def sled_system() -> tuple[MechanicalSystem, VelocityConstraint]:
    """The symbolic sled and its two-component constraint."""
    import sympy as sp

    from vnhc_gym.mechanics import MechanicalSystem, VelocityConstraint

    x, y, th = sp.symbols("x y theta", real=True)
    xd, yd, thd = sp.symbols("xd yd thetad", real=True)
    m, inertia, a, v_ref = sp.symbols("m I a v_ref", positive=True)
    s, c = sp.sin(th), sp.cos(th)
    mass = sp.Matrix([[m, 0, -m * a * s], [0, m, m * a * c], [-m * a * s, m * a * c, inertia + m * a**2]])
    system = MechanicalSystem(
        name="sled", q=(x, y, th), qd=(xd, yd, thd), mass_matrix=mass,
        control_forces=sp.Matrix([[c, 0], [s, 0], [0, 1]]),
        params={m: 20.0, inertia: 2.0, a: 0.3, v_ref: 1.5},
    )
    phi = sp.Matrix([-s * xd + c * yd, c * xd + s * yd - v_ref])
    return system, VelocityConstraint(phi)


@cache
def make_sled() -> ConstrainedSystem:
    """The compiled sled; parameters ``(m, I, a, v_ref)``, defaults ``(20, 2, 0.3, 1.5)``."""
    return ConstrainedSystem.from_recipe(("sled",), sled_system, printed=printed_module("sled"))
