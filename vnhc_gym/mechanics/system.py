"""Mechanical control systems, defined symbolically.

A mechanical control system on ``Q = R^n`` with ``m`` controls is

.. math::

    M(q)\\,\\ddot q + \\dot M(q)\\,\\dot q - \\tfrac12 \\partial_q(\\dot q^\\top M(q)\\,\\dot q)
        = F_0(q, \\dot q) + \\sum_a u_a f^a(q),

with ``M`` the mass matrix (the Riemannian metric), ``F0 = -dV/dq + F_ext`` the
uncontrolled forces and ``f^a`` the control covectors.  Solving for the acceleration gives
the form used by the paper,

.. math::

    \\ddot q = a_0(q, \\dot q) + \\sum_a u_a Y^a(q),
    \\qquad a_0 = -\\Gamma(\\dot q, \\dot q) + M^{-1} F_0,
    \\qquad Y^a = M^{-1} f^a .

Nothing here knows about Gymnasium: this module is plain sympy.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import sympy as sp

from vnhc_gym.mechanics._checks import check_param

__all__ = ["MechanicalSystem"]


def _as_column(expr: object, rows: int, name: str) -> sp.Matrix:
    mat = sp.Matrix(expr)
    if mat.shape == (1, rows) and rows != 1:
        mat = mat.T
    if mat.shape != (rows, 1):
        raise ValueError(f"{name} must have {rows} entries, got shape {mat.shape}")
    return mat


@dataclass(frozen=True, eq=False)
class MechanicalSystem:
    """A mechanical control system given by its metric, forces and control covectors.

    Parameters
    ----------
    name : str
        Short identifier, used in generated-code file names and reprs.
    q, qd : sequence of sympy.Symbol
        Generalised coordinates and velocities (same length ``n``).
    mass_matrix : sympy.Matrix
        ``n x n`` symmetric positive-definite mass matrix ``M(q)``.
    control_forces : sympy.Matrix
        ``n x m`` matrix whose column ``a`` is the control covector ``f^a(q)``.
    potential : sympy.Expr, optional
        Potential energy ``V(q)``; contributes ``-dV/dq`` to ``F0``.
    external_force : sympy.Matrix, optional
        Non-conservative uncontrolled force ``F_ext(q, qd)`` (``n`` entries).
    params : mapping of sympy.Symbol to float
        Physical parameters that appear in the expressions, with default values.  They stay
        symbols in the generated code, so changing them never recompiles anything.  Every value
        must be finite, and > 0 for a symbol declared positive (``sp.Symbol("m", positive=True)``);
        the compiled model refuses other values by name too.

    Raises
    ------
    ValueError
        If the sizes disagree, the mass matrix is not symmetric, an expression uses an unknown
        symbol, or a parameter's default value is not finite (or not > 0 where declared positive).
    """

    name: str
    q: tuple[sp.Symbol, ...]
    qd: tuple[sp.Symbol, ...]
    mass_matrix: sp.Matrix
    control_forces: sp.Matrix
    potential: sp.Expr = field(default_factory=lambda: sp.Integer(0))
    external_force: sp.Matrix | None = None
    params: Mapping[sp.Symbol, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = len(self.q)
        if n == 0 or len(self.qd) != n:
            raise ValueError(f"q and qd must be non-empty and of equal length, got {n} and {len(self.qd)}")
        object.__setattr__(self, "q", tuple(self.q))
        object.__setattr__(self, "qd", tuple(self.qd))
        mass = sp.Matrix(self.mass_matrix)
        if mass.shape != (n, n):
            raise ValueError(f"mass_matrix must be {n}x{n}, got {mass.shape}")
        # Cheap structural check first; simplify only what is not already identical.
        if not mass.is_symmetric(simplify=False) and not mass.is_symmetric():
            raise ValueError("mass_matrix must be symmetric")
        object.__setattr__(self, "mass_matrix", mass)
        forces = sp.Matrix(self.control_forces)
        if forces.rows != n or forces.cols == 0:
            raise ValueError(f"control_forces must be {n} x m with m >= 1, got {forces.shape}")
        object.__setattr__(self, "control_forces", forces)
        object.__setattr__(self, "potential", sp.sympify(self.potential))
        ext = sp.zeros(n, 1) if self.external_force is None else _as_column(self.external_force, n, "external_force")
        object.__setattr__(self, "external_force", ext)
        params = dict(self.params)
        for sym, value in params.items():
            params[sym] = check_param(str(sym), value, getattr(sym, "is_positive", None) is True,
                                      "MechanicalSystem(params=...)")
        object.__setattr__(self, "params", params)
        allowed = set(self.q) | set(self.qd) | set(self.params)
        for label, expr in (("mass_matrix", mass), ("control_forces", forces), ("potential", self.potential),
                            ("external_force", ext)):
            unknown = sp.sympify(expr).free_symbols - allowed
            if unknown:
                raise ValueError(f"{label} uses symbols that are neither coordinates nor params: "
                                 f"{sorted(map(str, unknown))}")

    @property
    def n(self) -> int:
        """Number of configuration coordinates."""
        return len(self.q)

    @property
    def m(self) -> int:
        """Number of controls."""
        return int(self.control_forces.cols)

    @property
    def param_symbols(self) -> tuple[sp.Symbol, ...]:
        """Parameter symbols, in the order of the numeric parameter vector."""
        return tuple(self.params)

    def total_force(self) -> sp.Matrix:
        """``F0 = -dV/dq + F_ext``: every uncontrolled force."""
        grad_v = sp.Matrix([sp.diff(self.potential, qi) for qi in self.q])
        return -grad_v + self.external_force

    def drift(self) -> sp.Matrix:
        """Drift acceleration ``a0 = -Christoffel(qd, qd) + M^-1 F0`` (``n x 1``)."""
        qd = sp.Matrix(self.qd)
        mass = self.mass_matrix
        # Christoffel terms from the Euler-Lagrange equations: Mdot qd - 1/2 d/dq (qd^T M qd).
        m_dot = sp.zeros(self.n, self.n)
        for i, qi in enumerate(self.q):
            m_dot += sp.diff(mass, qi) * self.qd[i]
        kinetic2 = (qd.T * mass * qd)[0, 0]
        coriolis = m_dot * qd - sp.Matrix([sp.diff(kinetic2, qi) for qi in self.q]) / 2
        return self._solve_mass(self.total_force() - coriolis)

    def input_fields(self) -> sp.Matrix:
        """Input vector fields ``Y^a = M^-1 f^a`` as the columns of an ``n x m`` matrix."""
        return self._solve_mass(self.control_forces)

    def energy(self) -> sp.Expr:
        """Mechanical energy ``1/2 qd^T M qd + V(q)``."""
        qd = sp.Matrix(self.qd)
        return (qd.T * self.mass_matrix * qd)[0, 0] / 2 + self.potential

    def _solve_mass(self, rhs: sp.Matrix) -> sp.Matrix:
        mass = self.mass_matrix
        if mass.is_diagonal():
            return sp.Matrix(rhs.rows, rhs.cols, lambda i, j: rhs[i, j] / mass[i, i])
        return sp.simplify(mass.inv() * rhs)

    def default_param_values(self, overrides: Mapping[str, float] | None = None) -> list[float]:
        """Numeric parameter vector, defaults overridden by name.

        Raises
        ------
        ValueError
            If a name is unknown, or an override is not finite (or not > 0 where the symbol is
            declared positive).
        """
        values = {str(k): float(v) for k, v in self.params.items()}
        positive = dict(zip(values, self.param_positive, strict=True))
        for key, val in (overrides or {}).items():
            if key not in values:
                raise ValueError(f"unknown parameter {key!r}; valid names: {sorted(values)}")
            values[key] = check_param(key, val, positive[key], "default_param_values")
        return [values[str(k)] for k in self.params]

    @property
    def param_positive(self) -> tuple[bool, ...]:
        """Whether each parameter (in the order of ``param_symbols``) is declared positive."""
        return tuple(getattr(k, "is_positive", None) is True for k in self.params)

    def symbols(self) -> Sequence[sp.Symbol]:
        """All state symbols ``(q, qd)``."""
        return self.q + self.qd
