"""The task that `vnhc_gym.envs._step_template` runs on when imported as a module of its own.

It shows the two hooks every task module defines (the generated step and reset kernels of a real
task import its ``draw`` and ``observe`` instead): a point mass on a line
(`vnhc_gym.mechanics._placeholder_system`) that starts at 0 with a velocity in ``[-1, 1]`` and
observes ``(q, qd)``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from vnhc_gym.rng import uniform_ab


class Args(NamedTuple):
    """The task's own constants for its hooks (a real task's has its domain, scales, ...)."""

    speed: float


@njit(cache=True)
def draw(rng: np.ndarray, r: int, stage: int, state: np.ndarray, params: np.ndarray, aux: np.ndarray,
         args: Args) -> None:
    """A new episode: the start ``state``, from row ``r``'s stream ``rng``."""
    state[0] = 0.0
    state[1] = uniform_ab(rng, r, -args.speed, args.speed)


@njit(cache=True)
def observe(state: np.ndarray, phi: np.ndarray, aux: np.ndarray, args: Args, obs: np.ndarray,
            phi_sf: np.ndarray) -> int:
    """The observation ``obs``; 0 (no termination)."""
    obs[0] = state[0]
    obs[1] = state[1]
    return 0
