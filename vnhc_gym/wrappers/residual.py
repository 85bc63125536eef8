"""Residual reinforcement learning on top of the geometric law."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

from vnhc_gym.baselines.geometric import DEFAULT_GAIN

__all__ = ["ResidualAction", "ResidualPolicy"]


def _check_box_unit(space: gym.Space, what: str) -> None:
    if not isinstance(space, spaces.Box):
        raise TypeError(f"ResidualAction needs a Box {what} space, got {type(space).__name__}")


class ResidualAction(gym.ActionWrapper):
    """Learned residual on top of a base policy: ``applied = clip(base(obs) + scale * a, -1, 1)``.

    The agent's action ``a`` (in ``[-1, 1]``, clipped there first) is a correction of the base
    policy's action (by default the geometric law of :class:`vnhc_gym.baselines.GeometricController`,
    computed from the observation with the nominal model).  With ``a = 0`` the wrapped
    environment behaves exactly as the base policy alone.

    Parameters
    ----------
    env : gymnasium.Env
        Action space ``Box(-1, 1)``, observation space ``Box`` (otherwise ``TypeError``).
    base : object with ``predict``, optional
        Base policy (SB3 interface).  Default ``GeometricController(env)``.
    scale : float, default 0.2
        Largest residual, as a fraction of the action range.
    continuous : bool, default False
        Instead of adding the base action computed from the last observation, run the law
        *inside the integrator*: ``env.unwrapped.task.set_feedback("continuous", gain)``
        re-evaluates ``u*`` at every RK4 stage from the **true state** with the **nominal**
        parameters, and the residual ``scale * a`` (force ``scale * a * force_bound``) is held
        over the control period and added to it (the total force is clipped to the force
        bound at every stage).  Because the law then uses the true state, observation noise
        does not affect the base part (only the learned residual sees the noisy observation);
        the ``base`` argument is not used.  ``close()`` switches the feedback off again.
    gain : float, optional
        Gain of the in-loop law (``continuous=True``); default ``base.gain`` if the base has
        one, else 1.

    Notes
    -----
    ``reset`` stores the observation and calls ``base.reset()`` if the base has one.  Every
    ``step``'s ``info`` gets ``"base_action"`` and ``"residual_action"`` (float32, action units):
    in the default mode the base policy's action and ``scale * a``; with ``continuous=True``
    ``base_action`` is the in-loop law's mean contribution over the period (``force /
    force_bound - residual``, saturation included).
    """

    def __init__(self, env: gym.Env, base: Any = None, scale: float = 0.2, continuous: bool = False,
                 gain: float | None = None) -> None:
        _check_box_unit(env.action_space, "action")
        _check_box_unit(env.observation_space, "observation")
        box = env.action_space
        assert isinstance(box, spaces.Box)
        if not (np.all(box.low == -1.0) and np.all(box.high == 1.0)):
            raise TypeError(f"ResidualAction needs an action space Box(-1, 1), got low={box.low}, high={box.high}")
        if not (np.isfinite(scale) and scale >= 0):
            raise ValueError(f"scale must be a finite number >= 0, got {scale!r}")
        super().__init__(env)
        self.scale = float(scale)
        self.continuous = bool(continuous)
        self._dtype = box.dtype
        self._shape = box.shape
        self._last_obs: NDArray[Any] | None = None
        self._last_base = np.zeros(box.shape, dtype=self._dtype)
        self._last_residual = np.zeros(box.shape, dtype=self._dtype)
        if self.continuous:
            task = getattr(env.unwrapped, "task", None)
            if task is None or not hasattr(task, "set_feedback"):
                raise TypeError("continuous=True needs a vnhc_gym environment (env.unwrapped.task.set_feedback)")
            if gain is None:
                gain = float(np.mean(getattr(base, "gain", DEFAULT_GAIN))) if base is not None else DEFAULT_GAIN
            self.gain: Any = gain
            self._task = task
            self.base = base
            task.set_feedback("continuous", gain)
        else:
            if base is None:
                from vnhc_gym.baselines import GeometricController

                base = GeometricController(env) if gain is None else GeometricController(env, gain=gain)
            if not hasattr(base, "predict"):
                raise TypeError(f"base must have a predict(obs) method, got {type(base).__name__}")
            self.base = base
            self.gain = getattr(base, "gain", gain)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(seed=seed, options=options)
        self._last_obs = obs
        if self.base is not None and hasattr(self.base, "reset"):
            self.base.reset()
        return obs, info

    def base_action(self, obs: Any) -> NDArray[Any]:
        """The base policy's action for ``obs`` (zeros with ``continuous=True``)."""
        if self.continuous:
            return np.zeros(self._shape, dtype=self._dtype)
        a, _ = self.base.predict(obs, deterministic=True)
        return np.asarray(a, dtype=self._dtype).reshape(self._shape)

    def action(self, action: Any) -> NDArray[Any]:
        if self._last_obs is None:
            raise gym.error.ResetNeeded("call reset() before step()")
        a = np.asarray(action, dtype=np.float64).reshape(self._shape)
        residual = self.scale * np.clip(a, -1.0, 1.0)
        base = self.base_action(self._last_obs)
        self._last_base = base
        self._last_residual = residual.astype(self._dtype)
        return np.clip(base.astype(np.float64) + residual, -1.0, 1.0).astype(self._dtype)

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(self.action(action))
        self._last_obs = obs
        if self.continuous:
            bound = np.asarray(self._task.force_bound, dtype=np.float64)
            law = np.asarray(info["force"], dtype=np.float64) / bound - self._last_residual.astype(np.float64)
            info["base_action"] = law.astype(self._dtype)
        else:
            info["base_action"] = self._last_base
        info["residual_action"] = self._last_residual
        return obs, reward, terminated, truncated, info

    def close(self) -> None:
        if self.continuous:
            self._task.set_feedback("open")
        super().close()


class ResidualPolicy:
    """A residual agent and its base as one policy: ``clip(base(obs) + scale * agent(obs), -1, 1)``.

    For evaluating a residual agent on the *unwrapped* environment with the SB3 ``predict``
    interface (batched).  Only for ``ResidualAction(continuous=False)`` agents: the in-loop
    mode needs the environment (wrap it with :class:`ResidualAction` instead).
    """

    def __init__(self, agent: Any, base: Any, scale: float = 0.2, name: str = "residual") -> None:
        self.agent = agent
        self.base = base
        self.scale = float(scale)
        self.name = name

    def reset(self) -> None:
        if hasattr(self.base, "reset"):
            self.base.reset()

    def predict(self, obs: Any, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[NDArray[np.float32], None]:
        a, _ = self.agent.predict(obs, deterministic=deterministic)
        b, _ = self.base.predict(obs, deterministic=True)
        out = np.clip(np.asarray(b, dtype=np.float64) + self.scale * np.clip(np.asarray(a, dtype=np.float64), -1, 1),
                      -1.0, 1.0)
        return out.astype(np.float32), None
