"""The paper's two systems, each in its own module, plus the current-field library."""

from vnhc_gym.systems.currents import CURRENTS, CurrentField, get_current, random_field_params
from vnhc_gym.systems.flocking import FLOCKING_PRESETS, FlockingPreset, flocking_state, flocking_system, make_flocking
from vnhc_gym.systems.usv import USV_OUTPUTS, USV_PRESETS, USVPreset, make_usv, usv_system

__all__ = [
    "CURRENTS", "CurrentField", "FLOCKING_PRESETS", "FlockingPreset", "USV_OUTPUTS", "USV_PRESETS", "USVPreset",
    "flocking_state", "flocking_system", "get_current", "make_flocking", "make_usv", "random_field_params",
    "usv_system",
]
