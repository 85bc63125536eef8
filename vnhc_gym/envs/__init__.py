"""Environments built from a task definition: the single and vector envs, their configuration,
the pure JAX step every task shares and the batch that runs it.  The environment classes
themselves live in the task modules (`vnhc_gym.tasks`)."""

from vnhc_gym.envs.config import SCENARIOS, EnvConfig, TaskOptions, option
from vnhc_gym.envs.env import ConstraintEnv
from vnhc_gym.envs.vector import MAX_EPISODE_STEPS, ConstraintVectorEnv, vector_env_class

__all__ = ["ConstraintEnv", "ConstraintVectorEnv", "EnvConfig", "MAX_EPISODE_STEPS", "SCENARIOS", "TaskOptions",
           "option", "vector_env_class"]
