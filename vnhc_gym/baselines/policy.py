"""What every baseline shares: the task it reads, observation checks, and SB3's ``predict``."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["Policy", "RandomPolicy", "ZeroPolicy", "spaces_of", "task_of"]

Array = NDArray[np.float64]


def _part_of(env: Any, name: str, mark: str) -> Any:
    """The attribute ``name`` (an object with the attribute ``mark``) of a vnhc_gym environment or of
    what it wraps (its ``unwrapped``, then its ``env`` chain), or None."""
    obj = env
    for _ in range(64):
        for holder in (obj, getattr(obj, "unwrapped", None)):
            part = getattr(holder, name, None)
            if part is not None and hasattr(part, mark):
                return part
        obj = getattr(obj, "env", None)
        if obj is None:
            break
    return None


def task_of(env: Any) -> Any:
    """The configured [`Task`][vnhc_gym.tasks.base.Task] of a vnhc_gym environment (single, wrapped or
    vector), or ``TypeError``."""
    task = _part_of(env, "task", "controller_inputs")
    if task is None:
        raise TypeError(f"{type(env).__name__} is not a vnhc_gym environment (single, wrapped or vector): it has no "
                        f"task")
    return task


def spaces_of(env: Any) -> tuple[gym.Space, gym.Space]:
    """The single-environment observation and action spaces of a single or vector environment."""
    if hasattr(env, "single_observation_space"):
        return env.single_observation_space, env.single_action_space
    return env.observation_space, env.action_space


def checked_task_of(env: Any) -> Any:
    """`task_of` for a controller that reads the task's observations and writes its actions:
    ``ValueError`` if a wrapper changed the environment's spaces from the task's."""
    task = task_of(env)
    obs_space, act_space = spaces_of(env)
    if obs_space.shape != (task.obs_dim,) or act_space.shape != (task.act_dim,):
        raise ValueError(f"the environment's spaces {obs_space.shape}, {act_space.shape} are not its task's "
                         f"({task.obs_dim},), ({task.act_dim},) (a wrapper changed them?)")
    return task


def batch_of(env: Any) -> Any:
    """The `vnhc_gym.envs.runtime.Batch` of a vnhc_gym environment (single, wrapped or vector): what
    a reference that reads the environment's memory reads, or ``TypeError``."""
    batch = _part_of(env, "batch", "buf")
    if batch is None:
        raise TypeError(f"{type(env).__name__} is not a vnhc_gym environment: a reference reads its state")
    return batch


class Policy:
    """A policy with Stable-Baselines3's ``predict`` interface, on one observation or a batch.

    Subclasses set ``obs_dim``, ``act_dim`` and ``name`` and implement `act` (a batch of
    observations ``(n, d)`` to actions ``(n, m)`` in ``[-1, 1]``).  Stateful ones also implement
    [`reset_rows`][vnhc_gym.baselines.Policy.reset_rows] (called for the rows where a new episode
    starts) and [`applied`][vnhc_gym.baselines.Policy.applied] (told the action the environment
    really received, when another policy changed it).
    """

    obs_dim: int
    act_dim: int
    name: str = "policy"
    #: Whether `belief` gives the observations of an estimate the policy keeps (a filter's).
    keeps_estimate: bool = False

    def check_obs(self, obs: ArrayLike) -> tuple[Array, bool]:
        """``(batch, single)``: the observations as a ``(n, d)`` float64 array, and whether one was given."""
        o = np.asarray(obs, dtype=np.float64)
        if o.ndim == 1 and o.shape[0] == self.obs_dim:
            return o[None, :], True
        if o.ndim == 2 and o.shape[1] == self.obs_dim:
            return o, False
        raise ValueError(f"observation must have shape ({self.obs_dim},) or (n, {self.obs_dim}), got {o.shape}")

    def act(self, obs: Array) -> Array:
        raise NotImplementedError

    def belief(self, obs: Array) -> Array:
        """The observations ``(n, d)`` the policy believes it would have received without noise, after
        acting on ``obs``: those of its own estimate for a policy that keeps one (`keeps_estimate`),
        else ``obs`` itself."""
        return np.asarray(obs, dtype=np.float64)

    def reset_rows(self, rows: NDArray[np.bool_]) -> None:
        """New episodes start in ``rows`` of the next batch (stateless policies: nothing to do)."""

    def reset(self) -> None:
        """Forget every episode (stateless policies: nothing to do)."""

    def applied(self, action: ArrayLike) -> None:
        """The actions the environment received for the rows of the last
        [`predict`][vnhc_gym.baselines.Policy.predict] (shape ``(m,)`` or ``(n, m)``, in
        ``[-1, 1]``), when they differ from the predicted ones: a residual added to them, a wrapper
        clipped them.  A policy that predicts with the force it applied (an observer, an adaptive
        law) must predict with these.  Stateless policies: nothing to do."""

    def predict(self, observation: ArrayLike, state: Any = None, episode_start: ArrayLike | None = None,
                deterministic: bool = True) -> tuple[NDArray[np.float32], None]:
        """Actions for one observation ``(d,)`` or a batch ``(n, d)``: ``(action, None)``.

        The signature is Stable-Baselines3's; ``episode_start`` (a bool per row) tells a stateful
        policy where new episodes begin; the recurrent ``state`` is unused and returned as None.
        """
        o, single = self.check_obs(observation)
        if episode_start is not None:
            starts = np.asarray(episode_start, dtype=bool).reshape(-1)
            if starts.shape[0] != o.shape[0]:
                raise ValueError(f"episode_start must have {o.shape[0]} entries, got {starts.shape[0]}")
            if starts.any():
                self.reset_rows(starts)
        a = np.asarray(self.act(o), dtype=np.float32)
        return (a[0] if single else a), None

    def __call__(self, obs: ArrayLike) -> NDArray[np.float32]:
        return self.predict(obs)[0]


class ZeroPolicy(Policy):
    """Always action 0 (no force): the uncontrolled reference."""

    name = "zero"

    def __init__(self, env: Any = None, *, obs_dim: int | None = None, act_dim: int | None = None) -> None:
        if env is not None:
            obs_space, act_space = spaces_of(env)
            obs_dim, act_dim = int(np.prod(obs_space.shape or ())), int(np.prod(act_space.shape or ()))
        if obs_dim is None or act_dim is None:
            raise TypeError("pass an env or obs_dim= and act_dim=")
        self.obs_dim, self.act_dim = int(obs_dim), int(act_dim)

    def act(self, obs: Array) -> Array:
        return np.zeros((obs.shape[0], self.act_dim))

    def __repr__(self) -> str:
        return "ZeroPolicy()"


class RandomPolicy(ZeroPolicy):
    """Uniform random actions in ``[-1, 1]`` from its own seeded generator."""

    name = "random"

    def __init__(self, env: Any = None, seed: int | None = 0, *, obs_dim: int | None = None,
                 act_dim: int | None = None) -> None:
        super().__init__(env, obs_dim=obs_dim, act_dim=act_dim)
        self.seed = seed
        self.rng = np.random.default_rng(seed)

    def act(self, obs: Array) -> Array:
        return self.rng.uniform(-1.0, 1.0, size=(obs.shape[0], self.act_dim))

    def __repr__(self) -> str:
        return f"RandomPolicy(seed={self.seed})"
