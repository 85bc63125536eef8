"""A user's system as pure ``jax.numpy`` functions, lambdified from its derived law when it is first used.

The package's own systems are printed once and shipped (`vnhc_gym.systems.printed`); a system a user
defines (the tutorial's puck) has no printed module, so the environments lambdify its law with
sympy's JAX printer instead: the same functions, with the same names and signatures as a printed
module, built in memory from the sympy expressions.  Deriving and lambdifying takes sympy a second or
two for a small system, once per process.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any

import jax.numpy as jnp

if TYPE_CHECKING:
    import sympy as sp

    from vnhc_gym.mechanics.constraint import SymbolicLaw

__all__ = ["LambdifiedSystem"]


class LambdifiedSystem:
    """A derived law as the functions of a printed system module (see `vnhc_gym.mechanics.printing`):
    ``drift``, ``input_fields``, ``phi``, ``decoupling_matrix``, ``drift_term``, ``singular_sizes``,
    ``energy``, ``outputs``
    (and ``phi_h`` for a holonomic constraint), each of one state ``s`` and one parameter vector ``p``.

    Parameters
    ----------
    law : SymbolicLaw
        The derived law of the system and its constraint.
    outputs : mapping of str to sympy expression, optional
        Extra quantities of the state and parameters, as ``outputs(s, p)``.
    """

    def __init__(self, law: SymbolicLaw, outputs: Mapping[str, sp.Expr] | None = None) -> None:
        system = law.system
        self.NAME = system.name
        self.N, self.M = system.n, system.m
        self.STATE_NAMES = tuple(str(s) for s in (*system.q, *system.qd))
        self.PARAM_NAMES = tuple(str(s) for s in system.param_symbols)
        self.PARAM_DEFAULTS = tuple(float(system.params[s]) for s in system.param_symbols)
        self.PARAM_POSITIVE = tuple(system.param_positive)
        self.OUTPUT_NAMES = tuple(outputs or {})
        self.HOLONOMIC = law.phi_h is not None
        state, params = [*system.q, *system.qd], list(system.param_symbols)
        n, m = self.N, self.M
        self.drift = _function(state, params, list(law.a0), (n,))
        self.input_fields = _function(state, params, list(law.Y), (n, m))
        self.phi = _function(state, params, list(law.phi), (m,))
        self.decoupling_matrix = _function(state, params, list(law.C), (m, m))
        self.drift_term = _function(state, params, list(law.G), (m,))
        jn, yn = law.factor_sizes()
        self.singular_sizes = _function(state, params, [*jn, *yn], (2 * m,))
        self.energy = _function(state, params, [law.energy], ())
        self.outputs = _function(state, params, list((outputs or {}).values()), (len(self.OUTPUT_NAMES),))
        if law.phi_h is not None:
            self.phi_h = _function(state, params, list(law.phi_h), (m,))


def _function(state: list[sp.Symbol], params: list[sp.Symbol], exprs: list[sp.Expr], shape: tuple[int, ...]
              ) -> Callable[[Any, Any], Any]:
    """``f(s, p)``: ``exprs`` at the state and parameters, as an array of ``shape`` (constant entries
    take the state's dtype, as in a printed module)."""
    import sympy as sp

    fns = [sp.lambdify([state, params], e, modules="jax", cse=True) for e in exprs]

    def f(s: Any, p: Any) -> Any:
        s_list, p_list = [s[i] for i in range(len(state))], [p[i] for i in range(len(params))]
        values = [jnp.asarray(fn(s_list, p_list), dtype=s.dtype) + jnp.zeros_like(s[0]) for fn in fns]
        return jnp.reshape(jnp.stack(values), shape) if values else jnp.zeros(shape, s.dtype)

    return f
