"""Virtual constraints and the stabilising law of the paper's Theorem 2, derived symbolically.

For a velocity constraint ``phi(q, qd) = 0`` with ``m`` components (as many as controls):

.. math::

    C^{ba} = \\frac{\\partial \\phi^b}{\\partial \\dot q}\\, Y^a,
    \\qquad
    G(\\phi)^b = \\frac{\\partial \\phi^b}{\\partial q}\\,\\dot q
               + \\frac{\\partial \\phi^b}{\\partial \\dot q}\\, a_0,
    \\qquad
    u^* = C^{-1}\\,(-K \\phi - G(\\phi)).

Along the closed loop ``d phi/dt = G + C u = -K phi``, hence ``phi(t) = exp(-K t) phi(0)``.
With ``K = 0`` the same formula gives the invariance control ``u_hat`` of the manifold.

For a holonomic constraint ``phi_h(q) = 0`` (Remark 2) the machinery runs on
``psi = d phi_h / dt = (d phi_h / dq) qd`` and the law becomes
``u* = C^-1 (-K1 phi_h - K2 psi - G(psi))``, so ``phi_h'' + K2 phi_h' + K1 phi_h = 0``.
"""

from __future__ import annotations

from dataclasses import dataclass

import sympy as sp

from vnhc_gym.mechanics.system import MechanicalSystem

__all__ = ["VelocityConstraint", "HolonomicConstraint", "SymbolicLaw", "derive_law"]


@dataclass(frozen=True, eq=False)
class VelocityConstraint:
    """A (possibly nonlinear, possibly affine) velocity constraint ``phi(q, qd) = 0``.

    Parameters
    ----------
    phi : sympy.Matrix
        ``m x 1`` expressions in the system's ``q``, ``qd`` and parameters.
    """

    phi: sp.Matrix

    def __post_init__(self) -> None:
        object.__setattr__(self, "phi", sp.Matrix(self.phi).reshape(len(self.phi), 1))


@dataclass(frozen=True, eq=False)
class HolonomicConstraint:
    """A holonomic constraint ``phi_h(q) = 0``, stabilised through ``psi = d phi_h/dt``.

    Parameters
    ----------
    phi_h : sympy.Matrix
        ``m x 1`` expressions in ``q`` and parameters only.
    """

    phi_h: sp.Matrix

    def __post_init__(self) -> None:
        object.__setattr__(self, "phi_h", sp.Matrix(self.phi_h).reshape(len(self.phi_h), 1))


Constraint = VelocityConstraint | HolonomicConstraint


@dataclass(frozen=True, eq=False)
class SymbolicLaw:
    """Every symbolic ingredient of the stabilising law for one (system, constraint) pair.

    Attributes
    ----------
    phi : sympy.Matrix
        Velocity constraint (``psi`` for a holonomic constraint), ``m x 1``.
    phi_h : sympy.Matrix or None
        Holonomic constraint values, or ``None`` for a velocity constraint.
    C : sympy.Matrix
        ``m x m`` decoupling matrix ``C[b, a] = d phi^b / d qd . Y^a``.
    G : sympy.Matrix
        ``m x 1`` Lie derivative of ``phi`` along the drift.
    a0, Y : sympy.Matrix
        Drift acceleration (``n x 1``) and input fields (``n x m``).
    energy : sympy.Expr
        Mechanical energy.
    """

    system: MechanicalSystem
    phi: sp.Matrix
    phi_h: sp.Matrix | None
    C: sp.Matrix
    G: sp.Matrix
    a0: sp.Matrix
    Y: sp.Matrix
    energy: sp.Expr

    @property
    def holonomic(self) -> bool:
        """Whether the constraint is holonomic (gains ``K1, K2``) or a velocity one (gain ``K``)."""
        return self.phi_h is not None

    @property
    def n_gains(self) -> int:
        """Length of the gain vector: ``m`` (``diag K``) or ``2 m`` (``diag K1``, ``diag K2``)."""
        return 2 * self.system.m if self.holonomic else self.system.m

    def factor_sizes(self) -> tuple[sp.Matrix, sp.Matrix]:
        """Squared sizes, in the metric, of the two factors of ``C = J Y`` (``J = d phi/d qd``).

        Returns
        -------
        (jn, yn) : sympy.Matrix, each ``m x 1``
            ``jn[b] = J_b M^-1 J_b^T``, the squared size of the covector ``J_b`` (row ``b`` of
            ``J``) in the inverse metric, and ``yn[a] = Y^a . M Y^a = f^a . Y^a``, the squared size
            of the input field ``Y^a``.  By Cauchy-Schwarz ``|C^{ba}| <= sqrt(jn[b] yn[a])``: the
            normalised ``C^{ba} / sqrt(jn[b] yn[a])`` is the cosine of the angle between the
            gradient of ``phi^b`` and ``Y^a``, the quantity of the law's singular test.
        """
        system = self.system
        jac = self.phi.jacobian(sp.Matrix(system.qd))
        lifted = system._solve_mass(jac.T)  # column b: M^-1 J_b^T, the gradient of phi^b as a vector
        forces = system.control_forces
        m = system.m
        # Simplified: the sizes often lose every trigonometric factor (sin^2 + cos^2 = 1), which
        # keeps the singular test cheap on the law's hot path.
        jn = sp.Matrix([sp.simplify(sum(jac[b, i] * lifted[i, b] for i in range(system.n))) for b in range(m)])
        yn = sp.Matrix([sp.simplify(sum(forces[i, a] * self.Y[i, a] for i in range(system.n))) for a in range(m)])
        return jn, yn

    def control(self, gains: sp.Matrix | None = None) -> sp.Matrix:
        """Closed-form ``u* = C^-1 (-K phi - G)`` (for display; the numeric path solves ``C u = r``)."""
        m = self.system.m
        k = sp.zeros(self.n_gains, 1) if gains is None else sp.Matrix(gains)
        if self.phi_h is None:
            rhs = -sp.diag(*k[:m]) * self.phi - self.G
        else:
            rhs = -sp.diag(*k[:m]) * self.phi_h - sp.diag(*k[m:]) * self.phi - self.G
        return sp.simplify(self.C.LUsolve(rhs))


def _check_symbols(expr: sp.Matrix, allowed: set[sp.Symbol], what: str) -> None:
    unknown = expr.free_symbols - allowed
    if unknown:
        raise ValueError(f"{what} uses unknown symbols {sorted(map(str, unknown))}")


def derive_law(system: MechanicalSystem, constraint: Constraint) -> SymbolicLaw:
    """Derive ``C``, ``G`` and the pieces of ``u*`` for ``constraint`` on ``system``.

    Parameters
    ----------
    system : MechanicalSystem
        The controlled mechanical system.
    constraint : VelocityConstraint or HolonomicConstraint
        The virtual constraint; it must have exactly ``system.m`` components.

    Returns
    -------
    SymbolicLaw
        The symbolic pieces; compile them with
        [`vnhc_gym.mechanics.ConstrainedSystem`][vnhc_gym.mechanics.ConstrainedSystem].

    Raises
    ------
    ValueError
        If the constraint's size differs from the number of controls, or it uses symbols the
        system does not define (a holonomic constraint may not use velocities).
    """
    q = sp.Matrix(system.q)
    qd = sp.Matrix(system.qd)
    params = set(system.params)
    if isinstance(constraint, HolonomicConstraint):
        phi_h = constraint.phi_h
        _check_symbols(phi_h, set(system.q) | params, "phi_h (a holonomic constraint depends on q only)")
        phi = phi_h.jacobian(q) * qd
    elif isinstance(constraint, VelocityConstraint):
        phi_h = None
        phi = constraint.phi
        _check_symbols(phi, set(system.q) | set(system.qd) | params, "phi")
    else:
        raise TypeError("constraint must be a VelocityConstraint or HolonomicConstraint, "
                        f"got {type(constraint).__name__}")
    if phi.rows != system.m:
        raise ValueError(f"constraint has {phi.rows} components but the system has {system.m} controls; "
                         "Theorem 2 needs a square C")
    a0 = system.drift()
    inputs = system.input_fields()
    dphi_dq = phi.jacobian(q)
    dphi_dqd = phi.jacobian(qd)
    c_mat = dphi_dqd * inputs
    g_vec = dphi_dq * qd + dphi_dqd * a0
    return SymbolicLaw(system=system, phi=phi, phi_h=phi_h, C=c_mat, G=g_vec, a0=a0, Y=inputs,
                       energy=system.energy())
