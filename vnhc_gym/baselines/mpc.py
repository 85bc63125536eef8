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

Why scipy, not CasADi: the prediction model is the package's own compiled step map (the same
kernels the environment integrates, generated from each task's symbolic model), so nothing has to
be derived a second time in another modelling language and the plan predicts exactly what the
nominal environment does.  The problem is small and box-constrained (``horizon x m`` variables
per row), which is what scipy's L-BFGS-B solves; its gradient is a forward difference computed
for every variable of every row in one batched rollout of the kernels.  The solve time per step
is kept (``solve_seconds``, ``n_solves``) so that it can be reported beside the score.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from vnhc_gym.baselines.geometric import DEFAULT_GAIN, GeometricController

__all__ = ["MPCController"]

Array = NDArray[np.float64]
#: The cost of a predicted trajectory that left the finite numbers (the optimiser backs away from it).
_DIVERGED = 1e12


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
        Largest number of L-BFGS-B iterations per control step.
    fd_step : float, default 1e-6
        Step of the forward differences, in units of the normalised action.
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
                 fd_step: float = 1e-6, limit_weight: float = 1e4, limit_margin: float = 0.9) -> None:
        super().__init__(env, gain=gain)
        for name, value in (("horizon", horizon), ("iters", iters)):
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
        if not (np.isfinite(fd_step) and 0 < fd_step < 1e-2):
            raise ValueError(f"fd_step must be a number in (0, 0.01), got {fd_step!r}")
        if not (np.isfinite(limit_weight) and limit_weight >= 0):
            raise ValueError(f"limit_weight must be a finite number >= 0, got {limit_weight!r}")
        if not (np.isfinite(limit_margin) and 0 < limit_margin <= 1):
            raise ValueError(f"limit_margin must be a number in (0, 1], got {limit_margin!r}")
        self.horizon, self.max_iters, self.fd_step = int(horizon), int(iters), float(fd_step)
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

    def __repr__(self) -> str:
        return f"MPCController({self.task.name!r}, gain={self.gain.tolist()}, horizon={self.horizon})"

    def _costs(self, x0: Array, params: Array, ref: Array, plans: Array) -> Array:
        """The cost of each plan: ``plans`` ``(R, N, m)`` from states ``x0`` ``(R, 2n)``."""
        x = x0
        cost = np.zeros(x0.shape[0])
        for k in range(self.horizon):
            x, _, _ = self.model.step(x, self.dt, u=plans[:, k] * self.bound, params=params, substeps=self.substeps)
            err = (self.model.phi(x, params) - ref[:, k]) / self.scale
            cost += np.sum(err * err, axis=1)
            if self.limit_weight and self.limit_index.size:
                over = np.maximum(np.abs(x[:, self.limit_index]) / self.limit_bound - self.limit_margin, 0.0)
                cost += self.limit_weight * np.sum(over * over, axis=1)
        return np.where(np.isfinite(cost), cost, _DIVERGED)

    def plan(self, states: Array, params: Array, start: Array) -> Array:
        """The optimal plans ``(B, N, m)`` (normalised actions) from ``states``, starting the search
        at ``start``."""
        from scipy.optimize import minimize

        b, n, m = states.shape[0], self.horizon, self.act_dim
        decay = np.exp(-np.outer(np.arange(1, n + 1) * self.dt, self.gain))  # (N, m_c)
        ref = decay[None] * self.model.phi(states, params)[:, None, :]  # (B, N, m_c)
        # One batched rollout per evaluation: each row's plan, then each of its N m coordinates nudged.
        width = 1 + n * m
        nudge = np.concatenate([np.zeros((1, n * m)), self.fd_step * np.eye(n * m)]).reshape(width, n, m)
        x0 = np.repeat(states, width, axis=0)
        p = np.repeat(params, width, axis=0)
        r = np.repeat(ref, width, axis=0)

        def cost_and_gradient(z: Array) -> tuple[float, Array]:
            plans = (z.reshape(b, 1, n, m) + nudge[None]).reshape(b * width, n, m)
            c = self._costs(x0, p, r, plans).reshape(b, width)
            return float(c[:, 0].sum()), ((c[:, 1:] - c[:, :1]) / self.fd_step).ravel()

        res = minimize(cost_and_gradient, np.clip(start, -1.0, 1.0).ravel(), jac=True, method="L-BFGS-B",
                       bounds=[(-1.0, 1.0)] * (b * n * m), options={"maxiter": self.max_iters})
        return np.clip(res.x.reshape(b, n, m), -1.0, 1.0)

    def act(self, obs: Array) -> Array:
        t0 = time.perf_counter()
        states, params = self.task.controller_inputs(obs)
        u, singular = self.law(states, params)
        start = np.clip(np.nan_to_num(u / self.bound), -1.0, 1.0)
        a = start.copy()
        ok = np.isfinite(states).all(axis=1) & np.isfinite(params).all(axis=1)
        if ok.any():
            plans = self.plan(states[ok], params[ok], np.repeat(start[ok][:, None, :], self.horizon, axis=1))
            a[ok] = plans[:, 0]
        self.last_singular = np.asarray(singular)
        self.last_saturated = np.any(np.abs(a) >= 1.0, axis=1)
        self.solve_seconds += time.perf_counter() - t0
        self.n_solves += 1
        return a
