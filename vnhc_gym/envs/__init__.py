"""Gymnasium environments built on the geometric core."""

from vnhc_gym.envs.flocking_align import FlockingAlignEnv
from vnhc_gym.envs.task import SCENARIOS, TaskConfig
from vnhc_gym.envs.usv_stream import USVStreamEnv

__all__ = ["FlockingAlignEnv", "USVStreamEnv", "SCENARIOS", "TaskConfig"]
