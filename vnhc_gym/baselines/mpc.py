"""Model-predictive control of the constraint within the force bound: the planning baseline.

The law ``u* = C^-1 (-K phi - G(phi))`` asks for whatever force makes ``phi`` decay as
``exp(-K t)``; where that force exceeds the bound, the law is clipped and no longer knows what
it does.  `MPCController` plans instead: at every control step it chooses the held forces of the
next ``horizon`` control periods, each within the bound, that keep the nominal model's ``phi``
closest to the law's own target decay,

.. math::

    \\min_{|a_j| \\le 1} \\sum_{k=1}^{N} \\big\\| \\big(\\phi(x_k) - e^{-K k\\,dt}\\,\\phi(x_0)\\big) / s \\big\\|^2,
    \\qquad x_{k+1} = F(x_k, a_k\\,u_{max}),

(``s`` the task's ``phi_sf_scale``, ``F`` the environment's RK4 step map of one control period on
the nominal parameters) and applies the first.  A task's state limits (``Task.limits``: the
episode ends when ``|x_i| > b_i``) enter as a penalty
``w sum_k sum_i max(0, |x_{k,i}| / b_i - margin)^2`` on predicted states beyond ``margin`` of
the bound: ending an episode forfeits every later step's reward, so a plan that holds ``phi`` a
little worse but stays inside is the better one.  Where the bound does not bind, the law's sampled
variant reaches the target exactly, so the plan is the law; where it binds, the plan trades the
near term against the later steps and may start braking earlier than the clipped law.

Each episode's plan is its own problem, solved from the episode's own previous plan shifted by one
period (the first step of an episode starts from the law's force held over the horizon), so an
episode's actions never depend on which other episodes share its batch.

Why scipy and JAX, not CasADi: the prediction model is the system printed from the task's own
symbolic model as pure JAX functions (`vnhc_gym.systems.printed`, the same RK4 step map the
environment integrates), so nothing has to be derived a second time in another modelling language,
and JAX differentiates the whole rollout exactly.  The problem is small and box-constrained
(``horizon x m`` variables), which is what scipy's L-BFGS-B solves.  The solve time per step is
kept (``solve_seconds``, ``n_solves``) so that it can be reported beside the score.
"""

from __future__ import annotations

import time
from functools import cache, partial
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from numpy.typing import ArrayLike, NDArray

from vnhc_gym.baselines.geometric import DEFAULT_GAIN, GeometricController
from vnhc_gym.mechanics import functional as F

__all__ = ["MPCController", "plan_cost"]

Array = NDArray[np.float64]
#: The cost of a predicted trajectory that left the finite numbers (the optimiser backs away from it).
_DIVERGED = 1e12


def plan_cost(system: Any, dt: float, substeps: int, limit_index: tuple[int, ...], z: Any, x0: Any, p: Any,
              ref: Any, bound: Any, scale: Any, limit_bound: Any, limit_weight: float, limit_margin: float) -> Any:
    """The cost of one episode's plan ``z`` (``horizon x m`` normalised actions, flat) from ``x0``:
    the squared distance of the predicted ``phi`` to the target decay ``ref`` (``(horizon, m)``),
    plus the penalty on predicted states beyond ``limit_margin`` of their limits (pure JAX)."""
    plans = z.reshape(ref.shape[0], -1)
    idx = jnp.asarray(limit_index, dtype=jnp.int32)

    def period(x: Any, inputs: Any) -> tuple[Any, Any]:
        a, target = inputs
        nxt = F.rk4_step(system, x, p, a * bound, dt, substeps)
        err = (system.phi(nxt, p) - target) / scale
        cost = jnp.sum(err * err)
        if limit_index:
            over = jnp.maximum(jnp.abs(nxt[idx]) / limit_bound - limit_margin, 0.0)
            cost = cost + limit_weight * jnp.sum(over * over)
        return nxt, cost

    _, costs = jax.lax.scan(period, x0, (plans, ref))
    total = jnp.sum(costs)
    return jnp.where(jnp.isfinite(total), total, _DIVERGED)


@cache
def _cost_and_gradient(system: Any, dt: float, substeps: int, limit_index: tuple[int, ...]) -> Any:
    """`plan_cost` and its gradient compiled once per system, step and limits: every planner of the
    same task and step shares them (JAX compiles a jitted function once per function object)."""
    return jax.jit(jax.value_and_grad(partial(plan_cost, system, dt, substeps, limit_index)))


class MPCController(GeometricController):
    """Receding-horizon control of ``phi`` on the nominal model within the force bound (SB3 ``predict``).

    Parameters
    ----------
    env : gymnasium Env or VectorEnv
        A vnhc_gym environment (its task's nominal model, force bound, ``dt`` and ``substeps``).
    gain : float or array_like, default ``DEFAULT_GAIN`` (5)
        ``diag K`` of the target decay ``exp(-K t)``, as the law's.
    horizon : int, default 8
        Control periods planned ahead (``N``).
    iters : int, default 30
        Largest number of L-BFGS-B iterations per control step and episode.
    limit_weight : float, default 1e4
        Weight ``w`` of the state-limit penalty (0: ignore the limits).
    limit_margin : float, default 0.9
        Fraction of each limit beyond which the penalty starts.

    Attributes
    ----------
    solve_seconds, n_solves : float, int
        Wall time spent planning and the number of plans (one per control step and batch).
    """

    def __init__(self, env: Any, gain: ArrayLike = DEFAULT_GAIN, horizon: int = 8, iters: int = 30,
                 limit_weight: float = 1e4, limit_margin: float = 0.9) -> None:
        super().__init__(env, gain=gain)
        for name, value in (("horizon", horizon), ("iters", iters)):
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
        if not (np.isfinite(limit_weight) and limit_weight >= 0):
            raise ValueError(f"limit_weight must be a finite number >= 0, got {limit_weight!r}")
        if not (np.isfinite(limit_margin) and 0 < limit_margin <= 1):
            raise ValueError(f"limit_margin must be a number in (0, 1], got {limit_margin!r}")
        self.horizon, self.max_iters = int(horizon), int(iters)
        self.limit_weight, self.limit_margin = float(limit_weight), float(limit_margin)
        # The limits index the environment's state; a controller model of other coordinates
        # (the boat's, relative to the water) has none to check.
        own = self.model is self.task.model
        self.limit_index = np.array([i for _, i, _ in self.task.limits] if own else [], dtype=np.intp)
        self.limit_bound = np.array([b for _, _, b in self.task.limits] if own else [], dtype=np.float64)
        self.name = "mpc"
        self.scale = np.broadcast_to(np.asarray(self.task.phi_sf_scale, dtype=np.float64), (self.model.n_gains,))
        self.bound = np.broadcast_to(np.asarray(self.force_bound, dtype=np.float64), (self.act_dim,)).copy()
        self.solve_seconds = 0.0
        self.n_solves = 0
        self._value_and_grad = _cost_and_gradient(self.model.functions, float(self.dt), int(self.substeps),
                                                  tuple(int(i) for i in self.limit_index))
        self._plans: Array | None = None  # each row's last plan (B, N, m), the next solve's start
        self._fresh: NDArray[np.bool_] | None = None  # rows whose next plan starts from the law

    def reset_rows(self, rows: NDArray[np.bool_]) -> None:
        if self._fresh is not None and self._fresh.shape == rows.shape:
            self._fresh |= rows

    def reset(self) -> None:
        self._plans = None

    def __repr__(self) -> str:
        return f"MPCController({self.task.name!r}, gain={self.gain.tolist()}, horizon={self.horizon})"

    def plan(self, state: Array, params: Array, start: Array) -> Array:
        """One episode's optimal plan ``(N, m)`` (normalised actions) from ``state``, the search
        started at ``start``."""
        from scipy.optimize import minimize

        n = self.horizon
        decay = np.exp(-np.outer(np.arange(1, n + 1) * self.dt, self.gain))  # (N, m_c)
        ref = decay * self.model.phi(state[None], params[None])[0]
        args = (state, params, ref, self.bound, self.scale, self.limit_bound, self.limit_weight, self.limit_margin)

        def cost_and_gradient(z: Array) -> tuple[float, Array]:
            value, grad = self._value_and_grad(z, *args)
            return float(value), np.asarray(grad, dtype=np.float64)

        with jax.enable_x64(True):  # scoped: the plan needs float64, the user's settings stay
            res = minimize(cost_and_gradient, np.clip(start, -1.0, 1.0).ravel(), jac=True, method="L-BFGS-B",
                           bounds=[(-1.0, 1.0)] * start.size, options={"maxiter": self.max_iters})
        return np.clip(res.x.reshape(start.shape), -1.0, 1.0)

    def act(self, obs: Array) -> Array:
        t0 = time.perf_counter()
        states, params = self.task.controller_inputs(obs)
        u, singular = self.law(states, params)
        law = np.clip(np.nan_to_num(u / self.bound), -1.0, 1.0)
        b = states.shape[0]
        if self._plans is None or self._plans.shape[0] != b or self._fresh is None:
            self._plans = np.repeat(law[:, None, :], self.horizon, axis=1)
            self._fresh = np.ones(b, dtype=bool)
        # Each row's search starts from its own last plan shifted by one period (or from the law).
        start = np.concatenate([self._plans[:, 1:], self._plans[:, -1:]], axis=1)
        start[self._fresh] = law[self._fresh][:, None, :]
        a = law.copy()
        ok = np.isfinite(states).all(axis=1) & np.isfinite(params).all(axis=1)
        for r in np.flatnonzero(ok):
            self._plans[r] = self.plan(states[r], params[r], start[r])
            a[r] = self._plans[r, 0]
        self._fresh[:] = False
        self.last_singular = np.asarray(singular)
        self.last_saturated = np.any(np.abs(a) >= 1.0, axis=1)
        self.solve_seconds += time.perf_counter() - t0
        self.n_solves += 1
        return a
