"""How policies are measured: the evaluation protocol, the per-episode metrics and their statistics
([`vnhc_gym.stats`][vnhc_gym.stats])."""

from vnhc_gym.evaluation.metrics import HIGHER_IS_BETTER, METRICS, PHI_CAP_SF, SCORE, episode_metrics
from vnhc_gym.evaluation.protocol import AGGREGATE, TEST_SEED, VALIDATION_SEED, EvalResult, evaluate

__all__ = ["AGGREGATE", "EvalResult", "HIGHER_IS_BETTER", "METRICS", "PHI_CAP_SF", "SCORE", "TEST_SEED",
           "VALIDATION_SEED", "episode_metrics", "evaluate"]
