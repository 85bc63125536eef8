"""Training: hyperparameters in RL Zoo's format, training runs, and trained agents as policies."""

from vnhc_gym.training.agents import AgentPolicy, list_zoo, load_agent
from vnhc_gym.training.config import ALGOS, TrainConfig, code_fingerprint, resolve_env_id
from vnhc_gym.training.run import train

__all__ = ["ALGOS", "AgentPolicy", "TrainConfig", "code_fingerprint", "list_zoo", "load_agent", "resolve_env_id",
           "train"]
