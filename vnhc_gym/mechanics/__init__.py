"""The geometric core: mechanical control systems, virtual constraints, the stabilising law
of Theorem 2 and RK4 integration.  Pure sympy/numpy/JAX: nothing here imports Gymnasium.

The symbolic names ([`MechanicalSystem`][vnhc_gym.mechanics.MechanicalSystem], the constraints,
[`derive_law`][vnhc_gym.mechanics.derive_law]) are loaded on first use (PEP 562), so that running a
printed system never imports sympy.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from vnhc_gym.mechanics.fleet import FleetLayout
from vnhc_gym.mechanics.functional import FEEDBACK_MODES
from vnhc_gym.mechanics.integrate import Trajectory, simulate
from vnhc_gym.mechanics.model import (
    FLAG_NONFINITE,
    FLAG_SINGULAR,
    ConstrainedSystem,
    Feedback,
    SingularControlError,
)
from vnhc_gym.mechanics.sampled import sampled_control

if TYPE_CHECKING:
    from vnhc_gym.mechanics.constraint import HolonomicConstraint, SymbolicLaw, VelocityConstraint, derive_law
    from vnhc_gym.mechanics.system import MechanicalSystem

#: Names imported from a sympy module on first access.
_SYMBOLIC = {
    "HolonomicConstraint": "vnhc_gym.mechanics.constraint",
    "SymbolicLaw": "vnhc_gym.mechanics.constraint",
    "VelocityConstraint": "vnhc_gym.mechanics.constraint",
    "derive_law": "vnhc_gym.mechanics.constraint",
    "MechanicalSystem": "vnhc_gym.mechanics.system",
}

__all__ = [
    "ConstrainedSystem", "FEEDBACK_MODES", "FLAG_NONFINITE", "FLAG_SINGULAR", "Feedback", "FleetLayout",
    "HolonomicConstraint",
    "MechanicalSystem", "SingularControlError", "SymbolicLaw", "Trajectory", "VelocityConstraint", "derive_law",
    "sampled_control", "simulate",
]


def __getattr__(name: str) -> Any:
    module = _SYMBOLIC.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
