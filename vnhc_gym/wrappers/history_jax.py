"""The last few observations as one, on the pure-JAX environment: the compiled trainers' counterpart
of Stable-Baselines3's ``VecFrameStack`` (the ``frame_stack`` key of a hyperparameter file, the
history variant of PPO)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import jax.numpy as jnp

from vnhc_gym.envs.functional import EnvParams, EnvState, FunctionalEnv, Step

__all__ = ["HistoryEnv"]

Array = Any  # a jax.Array


@dataclass(frozen=True, eq=False)
class HistoryEnv(FunctionalEnv):
    """``env`` whose observation is its last ``frames`` observations, oldest first, with zeros before
    an episode's first (as ``VecFrameStack`` stacks them, and as a trained agent's numpy policy stacks
    them at evaluation).  The frames before the last ride in `EnvState.history`.  Build it with
    `HistoryEnv.around`; only `initial` and `transition` differ from the plain environment's, so its
    step, batched step and automatic reset carry the history (a restarted row starts from zeros).
    """

    frames: int = 4

    @classmethod
    def around(cls, env: FunctionalEnv, frames: int) -> HistoryEnv:
        if type(env) is not FunctionalEnv:
            raise ValueError(f"HistoryEnv stacks the observations of a plain FunctionalEnv, got {type(env).__name__}")
        if isinstance(frames, bool) or not isinstance(frames, int) or frames < 2:
            raise ValueError(f"frames must be an integer >= 2, got {frames!r}")
        return cls(task=env.task, default_params=env.default_params, substeps=env.substeps, reward=env.reward,
                   feedback=env.feedback, frames=frames)

    @property
    def obs_dim(self) -> int:
        return int(self.task.obs_dim) * self.frames

    def initial(self, key: Array, params: EnvParams) -> tuple[Array, EnvState]:
        obs, state = super().initial(key, params)
        before = jnp.zeros((self.frames - 1) * obs.shape[0], obs.dtype)
        return jnp.concatenate([before, obs]), state._replace(history=before)

    def transition(self, key: Array, state: EnvState, action: Array, params: EnvParams) -> tuple[EnvState, Step]:
        new, out = super().transition(key, state, action, params)
        before = jnp.concatenate([state.history, state.obs])[state.obs.shape[0]:]  # the oldest frame drops out
        return new._replace(history=before), out._replace(obs=jnp.concatenate([before, out.obs]))
