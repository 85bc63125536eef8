"""The mechanical systems, one module each: the paper's flock and boat (with the current-field library),
the sled on ice, the cart-pole and the spacecraft."""

from vnhc_gym.systems.cartpole import cartpole_system, make_cartpole
from vnhc_gym.systems.currents import CURRENTS, CurrentField, get_current, random_field_params
from vnhc_gym.systems.flocking import (
    FLOCKING_PRESETS,
    FlockingPreset,
    flocking_layout,
    flocking_state,
    flocking_system,
    make_flocking,
)
from vnhc_gym.systems.sled import make_sled, sled_system
from vnhc_gym.systems.spacecraft import make_spacecraft, spacecraft_system
from vnhc_gym.systems.usv import USV_OUTPUTS, USV_PRESETS, USVPreset, make_usv, usv_system

__all__ = [
    "CURRENTS", "CurrentField", "FLOCKING_PRESETS", "FlockingPreset", "USV_OUTPUTS", "USV_PRESETS", "USVPreset",
    "cartpole_system", "flocking_layout", "flocking_state", "flocking_system", "get_current", "make_cartpole",
    "make_flocking", "make_sled", "make_spacecraft", "make_usv", "random_field_params", "sled_system",
    "spacecraft_system", "usv_system",
]
