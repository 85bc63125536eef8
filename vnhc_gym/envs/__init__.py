"""Environments built from a task definition: the single and vector envs, their configuration,
episode kernels and runtime.  The environment classes themselves live in the task modules
(:mod:`vnhc_gym.tasks`)."""

from vnhc_gym.envs.config import SCENARIOS, EnvConfig
from vnhc_gym.envs.env import ConstraintEnv
from vnhc_gym.envs.vector import MAX_EPISODE_STEPS, ConstraintVectorEnv

__all__ = ["ConstraintEnv", "ConstraintVectorEnv", "EnvConfig", "MAX_EPISODE_STEPS", "SCENARIOS"]
