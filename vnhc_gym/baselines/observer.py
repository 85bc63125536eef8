"""The geometric law fed by a state observer: for noisy observations.

The plain law acts on each noisy observation as if it were the state, so the noise goes straight
into the force.  [`ObserverController`][vnhc_gym.baselines.ObserverController] keeps an estimate of
the state instead: it predicts the next state with the nominal model and the force it applied (one
RK4 step of the controller's model, the same map the environment integrates), then moves the
prediction a fraction ``alpha`` of the way towards the state read from the new observation (a
constant-gain observer; the angles of the task's ``angles`` are compared modulo 2 pi).  The law acts
on the estimate.  With an exact model the prediction carries the dynamics, so a small ``alpha``
averages the noise over about ``1 / alpha`` steps without lagging behind the motion; the model's own
error (a current known only locally, a mass that is off) sets how small ``alpha`` may go.  The gain
and ``alpha`` are chosen on validation episodes
([`vnhc_gym.baselines.tuning`][vnhc_gym.baselines.tuning]).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from vnhc_gym.baselines.geometric import DEFAULT_GAIN, StatefulLaw
from vnhc_gym.envs.config import check_number

__all__ = ["ObserverController"]

Array = NDArray[np.float64]


class ObserverController(StatefulLaw):
    """The stabilising law on a state estimate (see the module docstring).

    Parameters
    ----------
    env : gymnasium Env or VectorEnv
        A vnhc_gym environment (the task's nominal model, force bound, ``dt`` and ``substeps``).
    gain : float or array_like, default 5
    alpha : float, default 0.03
        Observer gain in ``(0, 1]``: the weight of the new observation (1: no observer).
    alpha_params : float, optional
        The same for the parameters read from the observation (a current's local model); default
        ``alpha``.

    Notes
    -----
    The estimate of a batch row starts from its first observation; ``predict(obs, episode_start=...)``
    (or [`reset`][vnhc_gym.baselines.Policy.reset]) restarts rows where a new episode begins, as the
    evaluation protocol and the residual wrappers do.
    """

    def __init__(self, env: Any, gain: ArrayLike = DEFAULT_GAIN, alpha: float = 0.03,
                 alpha_params: float | None = None) -> None:
        super().__init__(env, gain)
        self.alpha = check_number("alpha", alpha, low=0.0, low_open=True, high=1.0)
        self.alpha_params: float = self.alpha if alpha_params is None else check_number(
            "alpha_params", alpha_params, low=0.0, low_open=True, high=1.0)
        self.name = "observer"
        self._x: Array | None = None  # state estimates (B, 2n)
        self._p: Array | None = None  # parameter estimates (B, n_params)
        self._u: Array | None = None  # the forces applied since (B, m)
        self._fresh: NDArray[np.bool_] | None = None  # rows that start from their next observation
        self._t: NDArray[np.float64] | None = None  # observations seen in each row's episode

    def __repr__(self) -> str:
        return f"ObserverController({self.task.name!r}, gain={self.gain.tolist()}, alpha={self.alpha})"

    def reset(self) -> None:
        self._x = None

    def estimate(self, obs: Array) -> tuple[Array, Array]:
        """Update the estimates with a batch of observations and return ``(states, params)``."""
        y, py = self.task.controller_inputs(obs)
        b = y.shape[0]
        if self._x is None or self._x.shape[0] != b or self._u is None or self._p is None or self._fresh is None \
                or self._t is None:
            self._x, self._p = y.copy(), py.copy()
            self._u = np.zeros((b, self.act_dim))
            self._fresh = np.zeros(b, dtype=bool)
            self._t = np.ones(b)
            return self._x, self._p
        pred, _, _ = self.model.step(self._x, self.dt, u=self._u, params=self._p, substeps=self.substeps)
        pred, prior = self.task.recenter(pred, self._p)
        diff = y - pred
        for j in self.task.angles:
            diff[:, j] = (diff[:, j] + np.pi) % (2 * np.pi) - np.pi
        # The weight of the new observation: 1/t while the estimate is younger than 1/alpha steps
        # (the running mean, optimal for an exact model), alpha after.
        self._t += 1.0
        w = np.maximum(self.alpha, 1.0 / self._t)[:, None]
        wp = np.maximum(self.alpha_params, 1.0 / self._t)[:, None]
        x = pred + w * diff
        p = prior + wp * (py - prior)
        bad = self._fresh | ~np.isfinite(x).all(axis=1) | ~np.isfinite(p).all(axis=1)
        x[bad], p[bad] = y[bad], py[bad]
        self._t[bad] = 1.0
        self._x, self._p = x, p
        self._fresh[:] = False
        return x, p

    def act(self, obs: Array) -> Array:
        x, p = self.estimate(obs)
        self._estimate = (x, p)
        u, singular = self.law(x, p)
        a = np.clip(np.where(np.isfinite(u), u / self.force_bound, 0.0), -1.0, 1.0)
        # The force the environment receives from this action (``predict`` returns float32).
        self._u = a.astype(np.float32).astype(np.float64) * self.force_bound
        self.last_singular = np.asarray(singular)
        return a
