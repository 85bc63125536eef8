"""vnhc_gym: Gymnasium benchmark environments for virtual nonholonomic constraints.

Importing the package registers ``vnhc_gym/FlockingAlign-v0`` and ``vnhc_gym/USVStream-v0``;
``gym.make("vnhc_gym:vnhc_gym/FlockingAlign-v0")`` imports it for you.
"""

from gymnasium.envs.registration import register, registry

__version__ = "0.1.0"

#: Registered environment ids and their episode lengths (400 steps of 0.05 s = 20 s).
ENV_IDS = ("vnhc_gym/FlockingAlign-v0", "vnhc_gym/USVStream-v0")
MAX_EPISODE_STEPS = 400

_ENTRY = {
    "vnhc_gym/FlockingAlign-v0": ("vnhc_gym.envs.flocking_align:FlockingAlignEnv",
                                  "vnhc_gym.envs.vector:FlockingAlignVectorEnv"),
    "vnhc_gym/USVStream-v0": ("vnhc_gym.envs.usv_stream:USVStreamEnv", "vnhc_gym.envs.vector:USVStreamVectorEnv"),
}

for _id, (_entry, _vector_entry) in _ENTRY.items():
    if _id not in registry:
        register(id=_id, entry_point=_entry, vector_entry_point=_vector_entry, max_episode_steps=MAX_EPISODE_STEPS)


def __getattr__(name: str):  # lazy: importing vnhc_gym must not import SB3 / torch
    if name == "make_sb3_vec_env":
        from vnhc_gym.sb3 import make_sb3_vec_env

        return make_sb3_vec_env
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["ENV_IDS", "MAX_EPISODE_STEPS", "__version__"]
