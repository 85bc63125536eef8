"""How policies are measured: the evaluation protocol, the per-episode metrics and their statistics
(:mod:`vnhc_gym.stats`)."""

from vnhc_gym.evaluation.metrics import HIGHER_IS_BETTER, METRICS, episode_metrics
from vnhc_gym.evaluation.protocol import TEST_SEED, VALIDATION_SEED, EvalResult, evaluate

__all__ = ["EvalResult", "HIGHER_IS_BETTER", "METRICS", "TEST_SEED", "VALIDATION_SEED", "episode_metrics",
           "evaluate"]
