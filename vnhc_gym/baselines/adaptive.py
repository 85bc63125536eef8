"""The geometric law with its uncertain parameters estimated online: for model mismatch.

Under ``mismatch`` the true masses (and, for the USV, inertia and current strength) differ from the
nominal ones the plain law is told, so ``u*`` no longer cancels the drift and ``phi`` settles at
an offset.  [`AdaptiveController`][vnhc_gym.baselines.AdaptiveController] estimates the task's
``uncertain`` parameters from what it sees: each step it predicts the observed state with the
controller's model and the force it applied, and corrects the estimate by an extended Kalman filter
on the prediction error (`correct_estimate`: pure JAX of one episode, the Jacobian of the model's RK4
step map by forward-mode differentiation, batched over the rows by ``jax.vmap``).  The law then uses
the estimate.  Parameters are estimated as ``log`` of their ratio to the nominal
value, so they stay positive.
"""

from __future__ import annotations

from functools import cache
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from numpy.typing import ArrayLike, NDArray

from vnhc_gym.baselines.geometric import DEFAULT_GAIN, StatefulLaw
from vnhc_gym.envs.config import check_number
from vnhc_gym.mechanics import functional as F

__all__ = ["AdaptiveController", "correct_estimate"]

Array = NDArray[np.float64]


def correct_estimate(system: Any, move: Any, substeps: int, index: tuple[int, ...], angles: tuple[int, ...],
                     theta: Any, cov: Any, x: Any, p: Any, u: Any, y: Any, args: Any, dt: Any, noise: Any,
                     drift: Any) -> tuple[Any, Any]:
    """One episode's extended-Kalman update of the log-ratios ``theta`` of the parameters ``index``
    (pure JAX; batched by ``jax.vmap``).

    The prediction of the observed state ``y`` is one control period of RK4 from the last state ``x``
    with the force ``u`` applied since and the parameters ``p`` scaled by ``exp(theta)``, carried into
    the frame of ``y`` by the task's ``move`` (its pure ``recenter``, or None); its Jacobian in
    ``theta`` is exact (forward mode).  ``theta`` is a random walk of ``drift^2`` per step; the
    prediction error, with the ``angles`` wrapped, has covariance ``noise^2 I``.  Returns the new
    ``(theta, cov)``, ``theta`` clipped to ``[-1, 1]``; a non-finite result keeps the old ones.
    """
    idx = jnp.asarray(index, dtype=jnp.int32)

    def predict(th: Any) -> Any:
        # Not unrolled: differentiated, written-out substeps compile several times slower (F.sampled_law).
        nxt = F.rk4_step(system, x, p.at[idx].set(p[idx] * jnp.exp(th)), u, dt, substeps, unroll=False)
        return nxt if move is None else move(nxt, p, args)[0]

    k = theta.shape[0]
    prior = cov + drift**2 * jnp.eye(k)
    err = y - predict(theta)
    for j in angles:
        err = err.at[j].set((err[j] + jnp.pi) % (2 * jnp.pi) - jnp.pi)
    jac = jax.jacfwd(predict)(theta)
    s = jac @ prior @ jac.T + noise**2 * jnp.eye(y.shape[0])
    gain = jnp.linalg.solve(s, jac @ prior).T  # prior H^T S^-1 (S and the prior symmetric)
    new_theta, new_cov = theta + gain @ err, prior - gain @ jac @ prior
    good = jnp.all(jnp.isfinite(new_theta)) & jnp.all(jnp.isfinite(new_cov))
    return jnp.where(good, jnp.clip(new_theta, -1.0, 1.0), theta), jnp.where(good, new_cov, cov)


@cache
def _batched(system: Any, move: Any, substeps: int, index: tuple[int, ...], angles: tuple[int, ...]) -> Any:
    """`correct_estimate` compiled for a batch of rows, once per task's functions and settings."""
    def one(*a: Any) -> Any:
        return correct_estimate(system, move, substeps, index, angles, *a)

    return jax.jit(jax.vmap(one, in_axes=(0,) * 6 + (None,) * 4))


class AdaptiveController(StatefulLaw):
    """The stabilising law with online estimates of the task's uncertain parameters.

    Parameters
    ----------
    env : gymnasium Env or VectorEnv
    gain : float or array_like, default 5
    prior : float, default 0.3
        Standard deviation of the log-ratio prior (the mismatch scenario draws ratios in 0.7..1.3).
    noise : float, default 1e-3
        Standard deviation of the one-step prediction error of each state entry (the filter's
        measurement noise, in the state's units).
    drift : float, default 0.0
        Standard deviation of the parameters' random walk per step (0: constant parameters).
    """

    def __init__(self, env: Any, gain: ArrayLike = DEFAULT_GAIN, prior: float = 0.3, noise: float = 1e-3,
                 drift: float = 0.0) -> None:
        super().__init__(env, gain)
        names = self.model.param_names
        self.index = np.array([names.index(n) for n in self.task.uncertain], dtype=np.intp)
        self.prior = check_number("prior", prior, low=0.0, low_open=True, high=10.0)
        self.noise = check_number("noise", noise, low=0.0, low_open=True)
        self.drift = check_number("drift", drift, low=0.0)
        self.name = "adaptive"
        self._theta: Array | None = None  # log-ratio estimates (B, k)
        self._cov: Array | None = None  # their covariances (B, k, k)
        self._x: Array | None = None  # the last observed states
        self._p: Array | None = None  # the last parameters (nominal ones from the observation)
        self._u: Array | None = None  # the forces applied since
        self._fresh: NDArray[np.bool_] | None = None

    def __repr__(self) -> str:
        return f"AdaptiveController({self.task.name!r}, gain={self.gain.tolist()}, estimates {self.task.uncertain})"

    def reset(self) -> None:
        self._theta = None

    def _with(self, params: Array, theta: Array) -> Array:
        p = params.copy()
        p[:, self.index] = params[:, self.index] * np.exp(theta)
        return p

    def estimates(self, obs: Array) -> Array:
        """Update the estimates with a batch of observations; the parameters the law should use."""
        y, py = self.task.controller_inputs(obs)
        b, k = y.shape[0], self.index.size
        if self._theta is None or self._theta.shape[0] != b or self._x is None or self._p is None \
                or self._u is None or self._cov is None or self._fresh is None:
            self._theta = np.zeros((b, k))
            self._cov = np.tile(np.eye(k) * self.prior**2, (b, 1, 1))
            self._fresh = np.zeros(b, dtype=bool)
        elif k:
            run = _batched(self.task.controller_functions(), self.task.frame_functions()[0], int(self.substeps),
                           tuple(int(i) for i in self.index), tuple(self.task.angles))
            with jax.enable_x64(True):  # scoped: the filter needs float64, the user's settings stay
                theta, cov = run(self._theta, self._cov, self._x, self._p, self._u, y, self.task.args,
                                 float(self.dt), self.noise, self.drift)
            good = ~self._fresh
            self._theta[good] = np.asarray(theta)[good]
            self._cov[good] = np.asarray(cov)[good]
            self._theta[self._fresh] = 0.0
            self._cov[self._fresh] = np.eye(k) * self.prior**2
            self._fresh[:] = False
        self._x, self._p = y, py
        return self._with(py, self._theta)

    def act(self, obs: Array) -> Array:
        p = self.estimates(obs)
        states: Array = self._x  # type: ignore[assignment]  # set by estimates
        self._estimate = (states, p)
        u, singular = self.law(states, p)
        a = np.clip(np.where(np.isfinite(u), u / self.force_bound, 0.0), -1.0, 1.0)
        # The force the environment receives from this action (``predict`` returns float32).
        self._u = a.astype(np.float32).astype(np.float64) * self.force_bound
        self.last_singular = np.asarray(singular)
        return a
