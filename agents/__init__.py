"""Training configuration and scripts for the vnhc_gym agents.

* ``agents/hyperparams/<env>.yml``: hyperparameters (RL Baselines3 Zoo format, one section per
  algorithm; read with ``yaml.safe_load``).
* ``agents/train.py``: a thin script around :mod:`vnhc_gym.train` (same as ``vnhc-gym train``).
"""

from pathlib import Path

HYPERPARAMS_DIR = Path(__file__).resolve().parent / "hyperparams"

__all__ = ["HYPERPARAMS_DIR"]
