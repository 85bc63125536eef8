"""The geometric law with its uncertain parameters estimated online: for model mismatch.

Under ``mismatch`` the true masses (and, for the USV, inertia and current strength) differ from the
nominal ones the plain law is told, so ``u*`` no longer cancels the drift and ``phi`` settles at
an offset.  [`AdaptiveController`][vnhc_gym.baselines.AdaptiveController] estimates the task's
``uncertain`` parameters from what it sees: each step it predicts the observed state with the
controller's model and the force it applied, and corrects the estimate by an extended Kalman filter
on the prediction error (the Jacobian by finite differences through the model's RK4 step map).  The
law then uses the estimate.  Parameters are estimated as ``log`` of their ratio to the nominal
value, so they stay positive.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from vnhc_gym.baselines.geometric import DEFAULT_GAIN, StatefulLaw
from vnhc_gym.envs.config import check_number

__all__ = ["AdaptiveController"]

Array = NDArray[np.float64]


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

    def _predict(self, x: Array, params: Array, theta: Array, u: Array) -> Array:
        nxt, _, _ = self.model.step(x, self.dt, u=u, params=self._with(params, theta), substeps=self.substeps)
        return self.task.recenter(nxt, params)[0]

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
            # Extended Kalman filter on theta: prediction error of the observed state.
            theta, cov = self._theta, self._cov + np.eye(k) * self.drift**2
            pred = self._predict(self._x, self._p, theta, self._u)
            err = y - pred
            for j in self.task.angles:
                err[:, j] = (err[:, j] + np.pi) % (2 * np.pi) - np.pi
            h = 1e-4
            jac = np.empty((b, y.shape[1], k))
            for i in range(k):
                step = np.zeros(k)
                step[i] = h
                jac[:, :, i] = (self._predict(self._x, self._p, theta + step, self._u) - pred) / h
            s = jac @ cov @ jac.transpose(0, 2, 1) + np.eye(y.shape[1]) * self.noise**2
            gain = cov @ jac.transpose(0, 2, 1) @ np.linalg.inv(s)
            new_theta = theta + np.einsum("bij,bj->bi", gain, err)
            new_cov = cov - gain @ jac @ cov
            good = np.isfinite(new_theta).all(axis=1) & ~self._fresh
            self._theta[good] = np.clip(new_theta[good], -1.0, 1.0)
            self._cov[good] = new_cov[good]
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
