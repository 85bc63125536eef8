"""vnhc_gym: Gymnasium benchmark environments for virtual nonholonomic constraints.

Importing the package registers every task of `vnhc_gym.tasks` as ``vnhc_gym/<EnvName>-v0``
and ``-v1`` (``gym.make("vnhc_gym:vnhc_gym/USVStream-v1")`` imports it for you).
"""

from vnhc_gym.tasks import TASKS, env_id, env_ids, make_jax

__version__ = "0.3.0"

#: Episode length of the registered environments (400 steps of 0.05 s = 20 s).
MAX_EPISODE_STEPS = 400


def __getattr__(name: str):  # lazy: importing vnhc_gym must not import SB3 / torch
    if name == "make_sb3_vec_env":
        from vnhc_gym.sb3 import make_sb3_vec_env

        return make_sb3_vec_env
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["MAX_EPISODE_STEPS", "TASKS", "__version__", "env_id", "env_ids", "make_jax"]
