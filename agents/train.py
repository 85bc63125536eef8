"""Train an agent: ``python agents/train.py --algo ppo --env flocking --seed 0``.

The same as the console command ``vnhc-gym train`` (see :mod:`vnhc_gym.train`); the
hyperparameters are in ``agents/hyperparams/<env>.yml``.
"""

import sys

from vnhc_gym.train import main

if __name__ == "__main__":
    sys.exit(main())
