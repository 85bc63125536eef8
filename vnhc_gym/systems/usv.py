"""An unmanned surface vehicle (USV) in a sea current (paper, Section IV-B).

``q = (x, y, theta)``, mass ``m``, inertia ``I``, current ``C(x, y) = s * (C1, C2)`` with
``s = current_scale`` (see `vnhc_gym.systems.currents`).  One control ``u``, covector
``f = sin(theta) dx - cos(theta) dy + d theta``:

.. math::

    m \\ddot x = u \\sin\\theta + W^1,\\quad m \\ddot y = -u\\cos\\theta + W^2,\\quad I\\ddot\\theta = u,

where ``W = m dV/dt`` along the motion and ``V = (sin^2 C1 - sin cos C2, -sin cos C1 + cos^2 C2)``
is the current's component normal to the heading.  The virtual affine constraint is

.. math::

    \\phi = \\sin\\theta\\,\\dot x - \\cos\\theta\\,\\dot y + \\cos\\theta\\, C^2 - \\sin\\theta\\, C^1
          = \\mu(\\dot q - C),\\qquad \\mu = \\sin\\theta\\,dx - \\cos\\theta\\,dy,

i.e. the boat's velocity relative to the water has no sideways component.  ``C = 1/m``
is never singular.  The law derived from Theorem 2 is
``u* = -m [k phi + thetad (xd cos theta + yd sin theta)]``: the current terms cancel in
``G(phi)`` (the paper's printed law is wrong; see the docs' errata page).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache, partial
from typing import TYPE_CHECKING

import numpy as np

from vnhc_gym.mechanics import ConstrainedSystem
from vnhc_gym.systems.currents import get_current
from vnhc_gym.systems.printed import printed_module

if TYPE_CHECKING:
    import sympy as sp

    from vnhc_gym.mechanics import MechanicalSystem, VelocityConstraint

__all__ = ["usv_system", "make_usv", "USVPreset", "USV_PRESETS", "USV_OUTPUTS"]

#: Names of the compiled extra outputs: the current at the boat and its Jacobian.
USV_OUTPUTS = ("C1", "C2", "dC1dx", "dC1dy", "dC2dx", "dC2dy")


def usv_system(current: str = "northeast") -> tuple[MechanicalSystem, VelocityConstraint, dict[str, sp.Expr]]:
    """Symbolic USV, its affine constraint and the current outputs, for a named current."""
    import sympy as sp

    from vnhc_gym.mechanics import MechanicalSystem, VelocityConstraint

    field = get_current(current)
    x, y, th = sp.symbols("x y theta", real=True)
    xd, yd, thd = sp.symbols("xd yd thetad", real=True)
    m, inertia, scale = sp.symbols("m I current_scale", positive=True)
    c1_raw, c2_raw = field.expressions(x, y)
    c1, c2 = scale * c1_raw, scale * c2_raw
    s, c = sp.sin(th), sp.cos(th)
    drift_velocity = sp.Matrix([s**2 * c1 - s * c * c2, -s * c * c1 + c**2 * c2])
    q = sp.Matrix([x, y, th])
    qd = sp.Matrix([xd, yd, thd])
    w = m * drift_velocity.jacobian(q) * qd  # W = m dV/dt along the motion
    params: dict[sp.Symbol, float] = {m: 10.0, inertia: 1.5, scale: 1.0}
    params.update({sym: field.defaults[k] for k, sym in field.symbols().items()})
    system = MechanicalSystem(
        name=f"usv_{current}", q=(x, y, th), qd=(xd, yd, thd),
        mass_matrix=sp.diag(m, m, inertia),
        control_forces=sp.Matrix([s, -c, 1]),
        external_force=sp.Matrix([w[0], w[1], 0]),
        params=params,
    )
    phi = sp.Matrix([s * xd - c * yd + c * c2 - s * c1])
    outputs = dict(zip(USV_OUTPUTS, [c1, c2, sp.diff(c1, x), sp.diff(c1, y), sp.diff(c2, x), sp.diff(c2, y)],
                       strict=True))
    return system, VelocityConstraint(phi), outputs


@cache
def make_usv(current: str = "northeast") -> ConstrainedSystem:
    """Compiled USV for a named current (cached per name).

    Parameters are ``(m, I, current_scale, c_<current params>...)``; see ``param_names``.
    A current with a printed module (`vnhc_gym.systems.printed`) runs it and does not import sympy;
    another is derived and lambdified on first use (see
    [`ConstrainedSystem.from_recipe`][vnhc_gym.mechanics.ConstrainedSystem.from_recipe]).
    """
    get_current(current)  # validates the name without building anything
    return ConstrainedSystem.from_recipe(("usv", current), partial(usv_system, current),
                                         printed=printed_module(f"usv_{current}"))


@dataclass(frozen=True)
class USVPreset:
    """A named parameter set and initial state for the USV."""

    name: str
    current: str
    q0: tuple[float, float, float]
    qd0: tuple[float, float, float]
    m: float
    inertia: float
    dt: float
    duration: float
    gain: float = 1.0
    description: str = ""

    def state(self) -> np.ndarray:
        return np.array([*self.q0, *self.qd0], dtype=np.float64)

    def params(self) -> np.ndarray:
        return make_usv(self.current).params(m=self.m, I=self.inertia)


#: Public preset names (keep them stable).
USV_PRESETS: dict[str, USVPreset] = {
    "paper-northeast": USVPreset("paper-northeast", "northeast", (1.0, 1.0, float(np.pi / 2)), (0.8, 0.5, 0.0),
                                 m=10.0, inertia=1.5, dt=0.01, duration=100.0,
                                 description="Section IV-B, north-east current C = (1, 1): m = 10, I = 1.5."),
    "paper-anticyclone": USVPreset("paper-anticyclone", "anticyclone", (1.0, 1.0, float(np.pi / 2)), (1.0, 1.0, 0.0),
                                   m=20.0, inertia=4.0, dt=0.01, duration=100.0,
                                   description="Section IV-B, anticyclone C = (y, -x + y): m = 20, I = 4 "
                                               "(starts on the manifold, phi(0) = 0)."),
}
