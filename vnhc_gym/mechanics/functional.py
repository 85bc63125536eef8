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

__all__ = ["FEEDBACK_MODES", "WithForces", "acceleration", "checked_law", "law", "measure", "rk4_step",
           "rk4_step_controlled",
           "sampled_law", "transversality", "vector_field"]

#: How the law enters a step (`rk4_step_controlled`): not at all, held over the period, or at every stage.
FEEDBACK_MODES = ("open", "continuous", "sampled")

Array = Any  # a jax.Array (or anything jax.numpy accepts)

_MAX_UNROLL = 8  #: RK4 loops up to this many substeps are unrolled


class WithForces:
    """A printed system with forces its model lacks: ``drift`` adds ``extra(s, p)``, the accelerations
    they cause; every other function (``phi``, ``C``, ``G``, ...) is the system's own.

    It stands where a printed module does (RK4, `sampled_law`): what the truth integrates, and what a
    reference that knows the truth plans with.
    """

    def __init__(self, system: ModuleType | WithForces, extra: Any) -> None:
        self._system = system
        self._extra = extra

    def __getattr__(self, name: str) -> Any:
        return getattr(self._system, name)

    def drift(self, s: Array, p: Array) -> Array:
        """The system's drift plus the extra accelerations."""
        return self._system.drift(s, p) + self._extra(s, p)


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


def rk4_step(system: ModuleType, s: Array, p: Array, u: Array, dt: float, substeps: int = 1,
             unroll: bool | None = None) -> Array:
    """The state after ``dt`` with ``u`` held (zero-order hold): ``substeps`` classic RK4 steps.

    ``unroll``: write the substeps out (default: up to ``_MAX_UNROLL`` of them).
    """
    h = dt / substeps

    def one(_: int, x: Array) -> Array:
        k1 = vector_field(system, x, p, u)
        k2 = vector_field(system, x + 0.5 * h * k1, p, u)
        k3 = vector_field(system, x + 0.5 * h * k2, p, u)
        k4 = vector_field(system, x + h * k3, p, u)
        return x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)

    # Unrolled where the loop is short (XLA fuses the stages); a long loop unrolled would make a
    # program of that many RK4 steps (100 000 substeps took 24 GB to compile).
    return jax.lax.fori_loop(0, substeps, one, s, unroll=substeps <= _MAX_UNROLL if unroll is None else unroll)


def transversality(system: ModuleType, s: Array, p: Array) -> Array:
    """How far the input fields are from tangent to the constraint: the law's singular test.

    The smallest singular value of ``C^{ba} / (|J_b| |Y^a|)``, with the squared sizes of
    ``system.singular_sizes`` (``|J_b|^2 = J_b M^-1 J_b^T`` then ``|Y^a|^2 = Y^a . M Y^a``): each
    normalised entry is the cosine of an angle in the metric, so the measure lies in ``[0, 1]``, 0
    where the inputs are tangent to the constraint, and rescaling masses, units, components or
    controls leaves it alone.  0 where a size vanishes, NaN where ``C`` or a size is not finite.  A
    system may supply its own (a fleet takes the smallest over its copies' blocks).
    """
    own = getattr(system, "transversality", None)
    if own is not None:
        return own(s, p)
    return measure(system.decoupling_matrix(s, p), system.singular_sizes(s, p))


def measure(c: Array, sizes: Array) -> Array:
    """`transversality` of a decoupling matrix ``c`` ``(m, m)`` from its factors' squared ``sizes`` ``(2m,)``."""
    m = c.shape[-1]
    finite = jnp.all(jnp.isfinite(c)) & jnp.all(jnp.isfinite(sizes))
    degenerate = jnp.any(sizes <= 0.0)
    ok = finite & ~degenerate
    safe = jnp.where(ok, sizes, 1.0)
    root = jnp.sqrt(safe)  # divided one factor at a time: a product of sizes may overflow
    normalised = jnp.where(ok, c, 0.0) / root[:m, None] / root[None, m:]
    smallest = jnp.min(jnp.linalg.svd(normalised, compute_uv=False))
    return jnp.where(finite, jnp.where(degenerate, 0.0, smallest), jnp.nan)


def checked_law(system: ModuleType, s: Array, p: Array, gains: Array,
                singular_tol: float | None) -> tuple[Array, Array]:
    """`law` with its singular test: ``(u, singular)``, ``u = 0`` where the state is singular.

    Singular: the `transversality` measure is not above ``singular_tol`` (``None``: no measure is
    taken), or the law is not finite.
    """
    u = law(system, s, p, gains)
    singular = ~jnp.all(jnp.isfinite(u))
    if singular_tol is not None:
        singular = singular | ~(transversality(system, s, p) > singular_tol)
    return jnp.where(singular, jnp.zeros_like(u), u), singular


def rk4_step_controlled(system: ModuleType, s: Array, p: Array, u: Array, dt: float, substeps: int = 1, *,
                        feedback: str = "open", p_law: Array | None = None, gains: Array = 1.0,
                        lower: Array = -jnp.inf, upper: Array = jnp.inf, singular_tol: float | None = None,
                        ) -> tuple[Array, Array, Array]:
    """One control period with the law in the loop: ``(new state, applied force, singular)``.

    The force at each RK4 stage is ``clip(u)`` (``feedback="open"``), ``clip(u + u*(start))`` held
    over the period (``"sampled"``, a zero-order hold) or ``clip(u + u*(stage))`` (``"continuous"``,
    the theorem's setting), clipped to ``[lower, upper]``.  The law reads the parameters ``p_law``
    (the model a controller is told; default ``p``) and is 0 where `checked_law` finds the state
    singular; ``singular`` says whether it did at any evaluation.  The applied force is averaged
    over the substeps' first stages.
    """
    pl = p if p_law is None else p_law
    if feedback == "open":
        held = jnp.clip(u, lower, upper)
        return rk4_step(system, s, p, held, dt, substeps), held, jnp.zeros((), bool)
    if feedback == "sampled":
        u_law, singular = checked_law(system, s, pl, gains, singular_tol)
        held = jnp.clip(u + u_law, lower, upper)
        return rk4_step(system, s, p, held, dt, substeps), held, singular
    if feedback != "continuous":
        raise ValueError(f"feedback must be one of {list(FEEDBACK_MODES)}, got {feedback!r}")
    h = dt / substeps

    def control(x: Array) -> tuple[Array, Array]:
        u_law, singular = checked_law(system, x, pl, gains, singular_tol)
        return jnp.clip(u + u_law, lower, upper), singular

    def field(x: Array) -> tuple[Array, Array]:
        force, singular = control(x)
        return vector_field(system, x, p, force), singular

    def one(_: int, carry: tuple[Array, Array, Array]) -> tuple[Array, Array, Array]:
        x, acc, seen = carry
        k1, s1 = field(x)
        k2, s2 = field(x + 0.5 * h * k1)
        k3, s3 = field(x + 0.5 * h * k2)
        k4, s4 = field(x + h * k3)
        first, _ = control(x)
        return (x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4), acc + first, seen | s1 | s2 | s3 | s4)

    x, acc, seen = jax.lax.fori_loop(0, substeps, one, (s, jnp.zeros_like(u), jnp.zeros((), bool)))
    return x, acc / substeps, seen


def sampled_law(system: ModuleType, s: Array, p: Array, dt: float, gains: Array, substeps: int = 1,
                iters: int = 4, *, phi_now: Array | None = None, xtol: float = 1e-10,
                singular_tol: float | None = None, bias: Array | None = None) -> tuple[Array, Array]:
    """The held control ``u`` with ``phi(F_dt(s, u)) = exp(-K dt) phi(s)``: the exact discretisation of
    the continuous closed loop for a zero-order hold (velocity constraints).  ``(u, converged)``.

    ``F_dt`` is `rk4_step`, the map an environment integrates with.  Newton's method from the law
    `checked_law` (0 where the state is singular; ``converged`` is then False), with the exact
    Jacobian ``d phi(F_dt(s, u)) / du`` by forward-mode differentiation.  With a measured
    ``phi_now`` the model gives only the increment, ``phi(F_dt(s, u)) - phi(s) = (exp(-K dt) - 1)
    phi_now``, so a bias between the model's ``phi(s)`` and the measurement cancels.  Newton stops
    when the residual is exactly 0 or a step is at most ``xtol * max(1, |u|)`` in every entry
    (``converged``); a step that would leave the finite numbers, or a non-finite end state, keeps
    the last iterate (``converged`` False), as does running out of ``iters`` steps.  ``bias`` is a
    rate of ``phi`` the model lacks (a disturbance observer's estimate), held over the period: the
    target becomes ``phi(F_dt(s, u)) + bias dt = exp(-K dt) phi(s)``.
    """
    if system.HOLONOMIC:
        raise ValueError("sampled_law supports velocity constraints only")
    m = system.M
    k = jnp.broadcast_to(jnp.asarray(gains, dtype=s.dtype), (m,))
    phi0 = system.phi(s, p)
    offset = phi0 + jnp.expm1(-k * dt) * (phi0 if phi_now is None else phi_now)
    if bias is not None:
        offset = offset - bias * dt

    def residual(u: Array) -> tuple[Array, tuple[Array, Array]]:
        # Not unrolled: differentiated, the written-out substeps of a large system (the boat in a
        # random current) took 18 s to compile against 4.6 s as a loop, for the same run time.
        end = rk4_step(system, s, p, u, dt, substeps, unroll=False)
        r = system.phi(end, p) - offset
        return r, (r, jnp.all(jnp.isfinite(end)) & jnp.all(jnp.isfinite(r)))

    def newton(_: int, carry: tuple[Array, Array, Array]) -> tuple[Array, Array, Array]:
        u, active, converged = carry
        jac, (r, finite) = jax.jacfwd(residual, has_aux=True)(u)
        zero = jnp.all(r == 0.0)
        converged = converged | (active & finite & zero)
        active = active & finite & ~zero
        du = jnp.linalg.solve(jac, r)
        new = u - du
        moved = active & jnp.all(jnp.isfinite(new))
        u = jnp.where(moved, new, u)
        small = jnp.all(jnp.abs(du) <= xtol * jnp.maximum(1.0, jnp.abs(u)))
        return u, moved & ~small, converged | (moved & small)

    start, singular = checked_law(system, s, p, k, singular_tol)
    u, active, converged = jax.lax.fori_loop(0, iters, newton, (start, ~singular, jnp.zeros((), bool)))
    r, finite = residual(u)[1]
    return u, converged | (active & finite & jnp.all(r == 0.0))
