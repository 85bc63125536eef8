"""RK4, the zero-order hold and the stabilising law as pure ``jax.numpy`` functions of one state.

``system`` is a printed system module (`vnhc_gym.mechanics.printing`: ``drift``, ``input_fields``,
``phi``, ``decoupling_matrix``, ``drift_term``, ...).  Every function here takes one state ``s``
(shape ``(2n,)``), one parameter vector ``p`` and plain arrays, returns arrays, and has no side
effects: ``jax.jit`` compiles it, ``jax.vmap`` batches it (over episodes, or over a fleet's
members), ``jax.grad``/``jax.jacfwd`` differentiate it, and the same code runs on a CPU or a GPU.

The precision is the caller's: float64 inputs under ``jax.enable_x64(True)`` give float64
results; nothing here changes JAX's global settings.
"""

from __future__ import annotations

from types import ModuleType
from typing import Any

import jax
import jax.numpy as jnp

__all__ = ["acceleration", "law", "rk4_step", "rk4_step_feedback", "sampled_law", "vector_field"]

Array = Any  # a jax.Array (or anything jax.numpy accepts)

_MAX_UNROLL = 8  #: RK4 loops up to this many substeps are unrolled


def acceleration(system: ModuleType, s: Array, p: Array, u: Array) -> Array:
    """``qdd = a0(s) + Y(s) u``: the system is affine in the control.

    The product is written as a sum of columns, not ``@``: batched by ``jax.vmap``, a matrix product
    of a few entries becomes a small batched matrix multiplication that XLA on a CPU does not fuse
    with the rest of the step (twice as slow for the sled's RK4 step, measured).
    """
    return system.drift(s, p) + jnp.sum(system.input_fields(s, p) * u, axis=-1)


def vector_field(system: ModuleType, s: Array, p: Array, u: Array) -> Array:
    """``d(q, qd)/dt = (qd, qdd)`` with the control ``u`` held."""
    return jnp.concatenate([s[system.N:], acceleration(system, s, p, u)])


def law(system: ModuleType, s: Array, p: Array, gains: Array) -> Array:
    """The stabilising law ``u* = C^-1 (-K phi - G)``.

    ``gains`` is ``diag K`` (``m`` values, or a scalar); for a holonomic constraint ``2m`` values,
    ``diag K1`` then ``diag K2``, and ``u* = C^-1 (-K1 phi_h - K2 phi - G)``.  Under it, ``phi``
    decays as ``exp(-K t)`` (``phi_h'' + K2 phi_h' + K1 phi_h = 0``) while ``C`` is invertible.
    """
    m = system.M
    k = jnp.broadcast_to(jnp.asarray(gains, dtype=s.dtype), (2 * m if system.HOLONOMIC else m,))
    rhs = -system.drift_term(s, p) - k[-m:] * system.phi(s, p)
    if system.HOLONOMIC:
        rhs = rhs - k[:m] * system.phi_h(s, p)
    return jnp.linalg.solve(system.decoupling_matrix(s, p), rhs)


def rk4_step(system: ModuleType, s: Array, p: Array, u: Array, dt: float, substeps: int = 1) -> Array:
    """The state after ``dt`` with ``u`` held (zero-order hold): ``substeps`` classic RK4 steps."""
    h = dt / substeps

    def one(_: int, x: Array) -> Array:
        k1 = vector_field(system, x, p, u)
        k2 = vector_field(system, x + 0.5 * h * k1, p, u)
        k3 = vector_field(system, x + 0.5 * h * k2, p, u)
        k4 = vector_field(system, x + h * k3, p, u)
        return x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)

    # Unrolled where the loop is short (XLA fuses the stages); a long loop unrolled would make a
    # program of that many RK4 steps (100 000 substeps took 24 GB to compile).
    return jax.lax.fori_loop(0, substeps, one, s, unroll=substeps <= _MAX_UNROLL)


def rk4_step_feedback(system: ModuleType, s: Array, p: Array, u: Array, dt: float, gains: Array,
                      substeps: int = 1, bound: Array | None = None) -> Array:
    """As `rk4_step`, with the law re-evaluated at every RK4 stage on top of the held ``u`` (the
    continuous-feedback reference); ``bound`` clips the total force per control."""

    def field(x: Array) -> Array:
        total = u + law(system, x, p, gains)
        if bound is not None:
            total = jnp.clip(total, -bound, bound)
        return vector_field(system, x, p, total)

    h = dt / substeps

    def one(_: int, x: Array) -> Array:
        k1 = field(x)
        k2 = field(x + 0.5 * h * k1)
        k3 = field(x + 0.5 * h * k2)
        k4 = field(x + h * k3)
        return x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)

    return jax.lax.fori_loop(0, substeps, one, s)


def sampled_law(system: ModuleType, s: Array, p: Array, dt: float, gains: Array, substeps: int = 1,
                iters: int = 4) -> Array:
    """The held control ``u`` with ``phi(F_dt(s, u)) = exp(-K dt) phi(s)``: the exact discretisation of
    the continuous closed loop for a zero-order hold (velocity constraints).

    ``F_dt`` is `rk4_step`, the map an environment integrates with.  Newton's method from ``u*``,
    with the exact Jacobian ``d phi(F_dt(s, u)) / du`` by forward-mode differentiation; a step
    that would leave the finite numbers keeps the previous iterate.
    """
    if system.HOLONOMIC:
        raise ValueError("sampled_law supports velocity constraints only")
    m = system.M
    k = jnp.broadcast_to(jnp.asarray(gains, dtype=s.dtype), (m,))
    target = jnp.exp(-k * dt) * system.phi(s, p)

    def residual(u: Array) -> Array:
        return system.phi(rk4_step(system, s, p, u, dt, substeps), p) - target

    def newton(_: int, u: Array) -> Array:
        step = jnp.linalg.solve(jax.jacfwd(residual)(u), residual(u))
        new = u - step
        return jnp.where(jnp.all(jnp.isfinite(new)), new, u)

    return jax.lax.fori_loop(0, iters, newton, law(system, s, p, k))
