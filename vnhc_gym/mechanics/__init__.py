"""The geometric core: mechanical control systems, virtual constraints, the stabilising law
of Theorem 2 and RK4 integration.  Pure sympy/numpy/numba: nothing here imports Gymnasium."""

from vnhc_gym.mechanics._kernels import FLAG_NONFINITE, FLAG_SINGULAR
from vnhc_gym.mechanics.constraint import HolonomicConstraint, SymbolicLaw, VelocityConstraint, derive_law
from vnhc_gym.mechanics.integrate import Trajectory, simulate
from vnhc_gym.mechanics.model import FEEDBACK_MODES, ConstrainedSystem, Feedback, SingularControlError
from vnhc_gym.mechanics.sampled import sampled_control
from vnhc_gym.mechanics.system import MechanicalSystem

__all__ = [
    "ConstrainedSystem", "FEEDBACK_MODES", "FLAG_NONFINITE", "FLAG_SINGULAR", "Feedback", "HolonomicConstraint",
    "MechanicalSystem", "SingularControlError", "SymbolicLaw", "Trajectory", "VelocityConstraint", "derive_law",
    "sampled_control", "simulate",
]
