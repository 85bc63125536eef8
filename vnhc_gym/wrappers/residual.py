"""Residual reinforcement learning on top of a model-based controller (by default the geometric law).

The agent's action ``a`` is a correction of the base controller's: the environment receives
``clip(base(obs) + scale * clip(a, -1, 1), -1, 1)``, so an agent that outputs 0 *is* the base
controller.  [`ResidualAction`][vnhc_gym.wrappers.ResidualAction] wraps a single environment (what
RL Zoo's ``env_wrapper`` builds); [`ResidualVectorAction`][vnhc_gym.wrappers.ResidualVectorAction]
wraps a native vector environment (what ``vnhc-gym train`` uses); `ResidualPolicy` runs a trained
residual agent with its base on the plain environment.  With ``observe_base=True`` the base action
is appended to the observation, so the agent sees what it corrects, and for a base that keeps an
estimate (the observer, the Kalman filter, the adaptive law) so is the observation of its estimate
(`vnhc_gym.baselines.Policy.belief`): what the base believes it would have seen without noise.
The agent's observation is then ``(obs, belief, base action)``.

A base with internal state (an observer, an adaptive law) predicts its next estimate with the force
it applied; all three classes tell it the action the environment really received
(``base.applied(...)``, [`vnhc_gym.baselines.Policy.applied`][vnhc_gym.baselines.Policy.applied]),
so exploration noise in the residual does not corrupt its estimate.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector import VectorWrapper
from numpy.typing import NDArray

from vnhc_gym.baselines.geometric import DEFAULT_GAIN
from vnhc_gym.envs.config import check_number

__all__ = ["ResidualAction", "ResidualPolicy", "ResidualVectorAction"]


def _check_spaces(obs_space: gym.Space, act_space: gym.Space) -> spaces.Box:
    if not isinstance(obs_space, spaces.Box):
        raise TypeError(f"residual learning needs a Box observation space, got {type(obs_space).__name__}")
    if not isinstance(act_space, spaces.Box) or not (np.all(act_space.low == -1.0) and np.all(act_space.high == 1.0)):
        raise TypeError(f"residual learning needs an action space Box(-1, 1), got {act_space}")
    return act_space


def _default_base(env: Any, base: Any, gain: float | None, settings: dict[str, Any] | None = None) -> Any:
    if base is None or isinstance(base, str):
        from vnhc_gym.baselines import make_classical

        kwargs = {"gain": DEFAULT_GAIN if gain is None else gain, **(settings or {})}
        return make_classical(base or "law", env, **kwargs)
    if not hasattr(base, "predict"):
        raise TypeError(f"base must have a predict(obs) method, got {type(base).__name__}")
    return base


def _tell_base(base: Any, applied: NDArray[Any]) -> None:
    """Tell a base policy the action the environment received (bases without state ignore it)."""
    hook = getattr(base, "applied", None)
    if callable(hook):
        hook(applied)


def _with_base(obs_space: spaces.Box, act_space: spaces.Box, belief: bool) -> spaces.Box:
    """The observation space with the base's belief (if it keeps an estimate) and action appended."""
    parts = [obs_space, obs_space, act_space] if belief else [obs_space, act_space]
    low = np.concatenate([p.low for p in parts]).astype(obs_space.dtype)
    high = np.concatenate([p.high for p in parts]).astype(obs_space.dtype)
    return spaces.Box(low, high, dtype=obs_space.dtype)  # type: ignore[arg-type]


def _seen(base: Any, obs: NDArray[Any], action: NDArray[Any], belief: bool) -> NDArray[Any]:
    """A batch ``(n, d)`` of observations as the agent sees them: with the base's belief (after it
    acted on ``obs``) if ``belief``, and the base's action ``(n, m)``."""
    parts = [obs, np.asarray(base.belief(obs)), action] if belief else [obs, action]
    return np.concatenate(parts, axis=1).astype(obs.dtype)


class ResidualAction(gym.Wrapper):
    """A learned residual on top of a base controller, for a single environment.

    Parameters
    ----------
    env : gymnasium.Env
        Action space ``Box(-1, 1)`` and a ``Box`` observation space (else ``TypeError``).
    base : object with ``predict``, or a name, optional
        The base controller (SB3 interface), or the name of a classical baseline
        (``"law"``, ``"tuned_law"``, ``"observer"``, ``"adaptive"``:
        [`vnhc_gym.baselines.CLASSICAL`][vnhc_gym.baselines.CLASSICAL]); default ``"law"``, the
        geometric law with gain ``gain``.
    scale : float, default 0.2
        Largest residual, as a fraction of the action range (0 to 1).
    gain : float, optional
        Gain of the default base (default 5).
    observe_base : bool, default False
        Append the base action to the observation (and, before it, the base's belief if it keeps
        an estimate).
    base_settings : dict, optional
        Keyword arguments of a base given by name (its gain, an observer's ``alpha``, ...).

    Notes
    -----
    Every ``info`` gets ``"base_action"`` and ``"residual_action"`` (action units).
    """

    def __init__(self, env: gym.Env, base: Any = None, scale: float = 0.2, gain: float | None = None,
                 observe_base: bool = False, base_settings: dict[str, Any] | None = None) -> None:
        box = _check_spaces(env.observation_space, env.action_space)
        super().__init__(env)
        self.scale: float = check_number("scale", scale, low=0.0, high=1.0)
        self.base = _default_base(env, base, gain, base_settings)
        self.observe_base = bool(observe_base)
        self._belief = self.observe_base and bool(getattr(self.base, "keeps_estimate", False))
        if self.observe_base:
            self.observation_space = _with_base(env.observation_space, box, self._belief)  # type: ignore[arg-type]
        self._dtype = box.dtype
        self._base_action = np.zeros(box.shape, dtype=box.dtype)

    def _observe(self, obs: NDArray[Any], start: bool) -> NDArray[Any]:
        a, _ = self.base.predict(obs, episode_start=np.array([start]), deterministic=True)
        self._base_action = np.asarray(a, dtype=self._dtype).reshape(self._base_action.shape)
        return _seen(self.base, obs[None], self._base_action[None], self._belief)[0] if self.observe_base else obs

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(seed=seed, options=options)
        return self._observe(obs, True), info

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        residual = self.scale * np.clip(np.asarray(action, dtype=np.float64).reshape(self._base_action.shape), -1, 1)
        applied = np.clip(self._base_action.astype(np.float64) + residual, -1.0, 1.0).astype(self._dtype)
        base = self._base_action
        _tell_base(self.base, applied)
        obs, reward, terminated, truncated, info = self.env.step(applied)
        info["base_action"] = base
        info["residual_action"] = residual.astype(self._dtype)
        return self._observe(obs, False), reward, terminated, truncated, info


class ResidualVectorAction(VectorWrapper):
    """[`ResidualAction`][vnhc_gym.wrappers.ResidualAction] for a vector environment (one
    ``predict`` of the base for all rows).

    Works in every autoreset mode: after a step, a sub-environment that starts a new episode (its
    returned observation is a reset's) tells a stateful base so through ``episode_start``.
    """

    def __init__(self, env: gym.vector.VectorEnv, base: Any = None, scale: float = 0.2, gain: float | None = None,
                 observe_base: bool = False, base_settings: dict[str, Any] | None = None) -> None:
        box = _check_spaces(env.single_observation_space, env.single_action_space)
        super().__init__(env)
        self.scale = check_number("scale", scale, low=0.0, high=1.0)
        self.base = _default_base(env, base, gain, base_settings)
        self.observe_base = bool(observe_base)
        self._belief = self.observe_base and bool(getattr(self.base, "keeps_estimate", False))
        if self.observe_base:
            self.single_observation_space = _with_base(env.single_observation_space, box,  # type: ignore[arg-type]
                                                       self._belief)
            self.observation_space = gym.vector.utils.batch_space(self.single_observation_space, env.num_envs)
        self._dtype = box.dtype
        self._base_action = np.zeros((env.num_envs, *box.shape), dtype=box.dtype)
        mode = env.metadata.get("autoreset_mode", gym.vector.AutoresetMode.NEXT_STEP)
        self._same_step = mode == gym.vector.AutoresetMode.SAME_STEP or mode == "SameStep"
        self._pending = np.zeros(env.num_envs, dtype=bool)

    def _observe(self, obs: NDArray[Any], starts: NDArray[np.bool_]) -> NDArray[Any]:
        a, _ = self.base.predict(obs, episode_start=starts, deterministic=True)
        self._base_action = np.asarray(a, dtype=self._dtype).reshape(self._base_action.shape)
        return _seen(self.base, obs, self._base_action, self._belief) if self.observe_base else obs

    def reset(self, *, seed: int | list[int | None] | None = None, options: dict[str, Any] | None = None
              ) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(seed=seed, options=options)  # type: ignore[arg-type]  # lists too
        n = self.num_envs
        mask = (options or {}).get("reset_mask")
        starts = np.ones(n, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
        self._pending &= ~starts
        if mask is not None:  # keep the base actions of the sub-environments not reset
            old = self._base_action.copy()
            out = self._observe(obs, starts)
            self._base_action[~starts] = old[~starts]
            return out, info
        return self._observe(obs, starts), info

    def step(self, actions: Any) -> tuple[Any, Any, Any, Any, dict[str, Any]]:
        residual = self.scale * np.clip(np.asarray(actions, dtype=np.float64).reshape(self._base_action.shape), -1, 1)
        applied = np.clip(self._base_action.astype(np.float64) + residual, -1.0, 1.0).astype(self._dtype)
        base = self._base_action
        _tell_base(self.base, applied)
        obs, reward, terminated, truncated, info = self.env.step(applied)
        done = np.asarray(terminated) | np.asarray(truncated)
        # SAME_STEP: done rows already show their new episode; NEXT_STEP: the rows done at the last
        # step were reset by this one.
        starts = done if self._same_step else self._pending
        self._pending = done & ~self._same_step
        info["base_action"] = base
        info["residual_action"] = residual.astype(self._dtype)
        if self.observe_base and "final_obs" in info:
            self._observe_final(info)
        return self._observe(obs, starts.copy()), reward, terminated, truncated, info

    def _observe_final(self, info: dict[str, Any]) -> None:
        """The last observations of finished episodes (``SAME_STEP``), with a base action appended.

        They only serve to bootstrap the value at a time limit, so the base action there is the
        law's from the observation alone, of the base's variant (plain or sampled-data), which keeps
        no state, and the belief is the observation itself: asking a stateful base would advance
        its estimate of the new episode.
        """
        from vnhc_gym.baselines import GeometricController

        rows = np.flatnonzero(info["_final_obs"])
        if rows.size == 0:
            return
        law = self.__dict__.get("_final_law")
        if law is None:
            law = self._final_law = GeometricController(self.env, gain=getattr(self.base, "gain", DEFAULT_GAIN),
                                                        variant=getattr(self.base, "variant", "plain"))
        obs = np.stack([info["final_obs"][i] for i in rows])
        a, _ = law.predict(obs)
        seen = _seen(law, obs, np.asarray(a, dtype=self._dtype), False)
        if self._belief:
            seen = np.concatenate([obs, seen], axis=1)
        final = info["final_obs"].copy()
        for j, i in enumerate(rows.tolist()):
            final[i] = seen[j]
        info["final_obs"] = final


class ResidualPolicy:
    """A residual agent and its base as one policy: ``clip(base(obs) + scale * agent(obs'), -1, 1)``
    (``obs'`` is ``obs`` with the base's belief, if it keeps an estimate, and action appended if the
    agent was trained with ``observe_base``)."""

    def __init__(self, agent: Any, base: Any, scale: float = 0.2, observe_base: bool = False,
                 name: str = "residual") -> None:
        self.agent = agent
        self.base = base
        self.scale = float(scale)
        self.observe_base = bool(observe_base)
        self.name = name

    def predict(self, observation: Any, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[NDArray[np.float32], Any]:
        obs = np.asarray(observation, dtype=np.float32)
        single = obs.ndim == 1
        batch = obs[None] if single else obs
        starts = None if episode_start is None else np.asarray(episode_start, dtype=bool).reshape(-1)
        b, _ = self.base.predict(batch, episode_start=starts, deterministic=True)
        b = np.asarray(b, dtype=np.float64).reshape(batch.shape[0], -1)
        belief = bool(getattr(self.base, "keeps_estimate", False))
        seen = _seen(self.base, batch, b.astype(np.float32), belief) if self.observe_base else batch
        a, state = self.agent.predict(seen, state=state, episode_start=starts, deterministic=deterministic)
        out = np.clip(b + self.scale * np.clip(np.asarray(a, dtype=np.float64).reshape(b.shape), -1, 1), -1.0, 1.0)
        out32 = out.astype(np.float32)
        _tell_base(self.base, out32)
        return (out32[0] if single else out32), state
