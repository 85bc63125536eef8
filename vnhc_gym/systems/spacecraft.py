"""A rigid spacecraft's attitude, turned by three body torques to spin about its axis 3 held vertical.

``q = (psi, theta, varphi)``: ZYX Euler angles, body-to-inertial rotation
``R = Rz(psi) Ry(theta) Rx(varphi)``.  The body angular velocity is ``omega = E(q) qd`` with

.. math::

    E = \\begin{pmatrix} -\\sin\\theta & 0 & 1 \\\\ \\cos\\theta\\sin\\varphi & \\cos\\varphi & 0 \\\\
        \\cos\\theta\\cos\\varphi & -\\sin\\varphi & 0 \\end{pmatrix}, \\qquad \\det E = -\\cos\\theta,

whose first column is ``z = R^T e_z``, the inertial vertical in body axes.  The kinetic energy
``T = 1/2 omega^T J omega`` with ``J = diag(J1, J2, J3)`` (principal inertias; the defaults
1, 1.5, 2 kg m^2 are distinct, so the free body shows the gyroscopic coupling and the
intermediate-axis instability) gives the attitude-dependent mass matrix ``M = E^T J E``,
``det M = J1 J2 J3 cos^2(theta)``.  Three controls: body torques ``tau`` (reaction wheels or
thrusters) about the principal axes, whose generalised forces are ``E^T tau``; the equations of
motion are Euler's ``J omegadot + omega x J omega = tau``.

The virtual constraint has three components,

.. math::

    \\phi = \\omega - \\lambda\\, e_3 \\times z - \\Omega\\, e_3
          = (\\omega_1 + \\lambda z_2,\\; \\omega_2 - \\lambda z_1,\\; \\omega_3 - \\Omega):

spin about body axis 3 at the rate ``Omega`` (either sign, or 0), while the transverse rate turns
axis 3 towards the vertical about ``e_3 x z``, at ``lam`` times the sine of the tilt.  Since
``d phi/d qd = E`` and ``Y = M^-1 E^T = E^-1 J^-1``, the decoupling matrix is constant,
``C = J^-1``, and with ``zdot = z x omega``

.. math::

    G = -J^{-1}(\\omega \\times J\\omega) + \\lambda\\,(\\dot z_2, -\\dot z_1, 0), \\qquad
    u^* = \\omega \\times J\\omega - J\\,\\big(K\\phi + \\lambda(\\dot z_2, -\\dot z_1, 0)\\big).

On ``phi = 0`` the tilt ``alpha`` of axis 3 from the vertical (``z_3 = cos alpha``) obeys
``z_3' = z_1 omega_2 - z_2 omega_1 = lam (1 - z_3^2)``, whatever the inertia and the spin:
``z_3(t) = tanh(lam t + artanh z_3(0))``, i.e. ``tan(alpha/2)`` decays as ``exp(-lam t)`` from any
tilt below pi, and ``w = z_1 + i z_2`` obeys ``w' = -(i Omega + lam z_3) w`` (it turns at
``-Omega`` in the body while it shrinks).  Every solution tends to the relative equilibrium
``theta = varphi = 0``, ``psid = Omega``: a steady spin about the vertical, the only attractor
(upside down, ``z_3 = -1``, is the only other equilibrium of the tilt, and repels).  ``psi``
winds up at about ``Omega`` rad/s, far inside the range of the kernels' inline sines for any
episode of realistic length.

Where the law is singular: nowhere in the sense of Theorem 2.  The squared sizes of the rows of
``d phi/d qd`` and of the input fields are ``J_b M^-1 J_b^T = 1/J_b`` and ``f^a . Y^a = 1/J_a``,
so the normalised ``C`` is the identity and the transversality measure is 1 at every attitude,
for every inertia.  The only singularity is the chart's: at ``theta = +-pi/2`` (body axis 1
vertical) ``E`` and ``M`` are singular, and the compiled drift and input fields divide by
``cos(theta)`` and ``cos(theta)^2``.  ``u*`` itself is a smooth function of ``(z, omega)``, and its
compiled form loses only about ``eps / cos(theta)^2`` to the cancellation; what fails first near
gimbal lock is integration in the angles, whose rates grow as ``|omega| / cos(theta)``.  The
constraint keeps clear of it: since ``|sin theta| = |z_1| <= sin alpha``, on ``phi = 0`` the pitch
never exceeds the initial tilt when that is at most pi/2; off it, under continuous feedback with
the gain ``k`` on ``phi_1`` and ``phi_2``, the tilt rate is at most ``-lam sin alpha + |phi_perp|``
with ``|phi_perp(t)| = exp(-k t) |phi_perp(0)|``, so the transient adds at most
``|phi_perp(0)| / k`` of tilt.  The target attitude ``theta = varphi = 0`` (axis 3 vertical) is the
centre of the chart, as far from gimbal lock as the ZYX angles allow.  The singular test cannot see
the chart's singularity, so a task needs its own termination near gimbal lock.
"""

from __future__ import annotations

from functools import cache
from typing import TYPE_CHECKING

from vnhc_gym.mechanics import ConstrainedSystem
from vnhc_gym.systems.printed import printed_module

if TYPE_CHECKING:
    from vnhc_gym.mechanics import MechanicalSystem, VelocityConstraint

__all__ = ["make_spacecraft", "spacecraft_system"]


def spacecraft_system() -> tuple[MechanicalSystem, VelocityConstraint]:
    """The symbolic spacecraft and its three-component spin-and-point constraint."""
    import sympy as sp

    from vnhc_gym.mechanics import MechanicalSystem, VelocityConstraint

    psi, th, ph = sp.symbols("psi theta varphi", real=True)
    psid, thd, phd = sp.symbols("psid thetad varphid", real=True)
    j1, j2, j3, lam = sp.symbols("J1 J2 J3 lam", positive=True)
    omega_ref = sp.Symbol("Omega", real=True)  # the spin may go either way, or be 0
    st, ct, sp_, cp = sp.sin(th), sp.cos(th), sp.sin(ph), sp.cos(ph)
    # omega = E(q) qd, the body angular velocity of R = Rz(psi) Ry(theta) Rx(varphi); the psi column
    # of E is the inertial vertical in body axes, z_b = R^T e_z.
    e_mat = sp.Matrix([[-st, 0, 1], [ct * sp_, cp, 0], [ct * cp, -sp_, 0]])
    inertia = sp.diag(j1, j2, j3)
    # Expanded: of the forms tried (the product E^T J E, entries collected by hand), the one whose
    # inverse sympy simplifies fastest; that simplification is most of the first-use time.
    mass = (e_mat.T * inertia * e_mat).applyfunc(sp.expand)
    system = MechanicalSystem(
        name="spacecraft", q=(psi, th, ph), qd=(psid, thd, phd), mass_matrix=mass,
        control_forces=e_mat.T,
        params={j1: 1.0, j2: 1.5, j3: 2.0, omega_ref: 1.0, lam: 1.0},
    )
    omega = e_mat * sp.Matrix([psid, thd, phd])
    z_b = e_mat[:, 0]
    phi = sp.Matrix([omega[0] + lam * z_b[1], omega[1] - lam * z_b[0], omega[2] - omega_ref])
    return system, VelocityConstraint(phi)


@cache
def make_spacecraft() -> ConstrainedSystem:
    """The compiled spacecraft; parameters ``(J1, J2, J3, Omega, lam)`` (kg m^2, kg m^2, kg m^2, rad/s,
    1/s), defaults ``(1, 1.5, 2, 1, 1)``."""
    return ConstrainedSystem.from_recipe(("spacecraft",), spacecraft_system, printed=printed_module("spacecraft"))
