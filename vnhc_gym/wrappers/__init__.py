"""Gymnasium wrappers: residual learning on top of the geometric law
([`ResidualAction`][vnhc_gym.wrappers.ResidualAction])."""

from vnhc_gym.wrappers.residual import ResidualAction, ResidualPolicy, ResidualVectorAction

__all__ = ["ResidualAction", "ResidualPolicy", "ResidualVectorAction"]
