"""Training: hyperparameters in RL Zoo's format, training runs, agents."""
