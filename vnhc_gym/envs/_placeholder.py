"""The task that :mod:`vnhc_gym.envs._template` runs on when imported as a module of its own.

It documents the two hooks every task module defines (the generated step and reset kernels of a
real task import its ``draw``, ``observe`` and ``DRAW_STAGES`` instead): a point mass on a line
(:mod:`vnhc_gym.mechanics._placeholder`) that starts at rest at 0 with a velocity in ``[-1, 1]``
and observes ``(q, qd)``.
"""

from __future__ import annotations

from typing import NamedTuple

from numba import njit

from vnhc_gym.envs.episode import STATUS_NONFINITE, STATUS_OK, Buffers, StepConfig
from vnhc_gym.kernels import uniform_ab
from vnhc_gym.mechanics.kernels import FLAG_NONFINITE

#: Number of drawing stages of a reset; stage ``k > 0`` may read ``buf.aux[r]``, the extra outputs
#: of the true model at the state drawn so far.
DRAW_STAGES = 1


class Args(NamedTuple):
    """The task's own constants for its kernels (a real task's has its domain, scales, ...)."""

    mass: float


@njit(cache=True)
def draw(r: int, stage: int, buf: Buffers, cfg: StepConfig, args: Args) -> None:
    """A new episode for row ``r``: ``buf.state[r]``, ``buf.params_true[r]``, ``buf.params_nominal[r]``,
    from row ``r``'s stream ``buf.rng``."""
    buf.state[r, 0] = 0.0
    buf.state[r, 1] = uniform_ab(buf.rng, r, -1.0, 1.0)
    buf.params_nominal[r, 0] = args.mass
    buf.params_true[r, 0] = args.mass


@njit(cache=True)
def observe(r: int, buf: Buffers, cfg: StepConfig, args: Args) -> None:
    """Row ``r``'s observation ``buf.obs[r]`` (clipped to ``cfg.obs_clip``), status ``buf.status[r]`` and
    scale-free ``buf.phi_sf[r]``, from the state, ``buf.phi[r]`` and ``buf.aux[r]``."""
    buf.status[r] = STATUS_NONFINITE if buf.flags[r] & FLAG_NONFINITE else STATUS_OK
    for j in range(2):
        buf.obs[r, j] = min(max(buf.state[r, j], -cfg.obs_clip), cfg.obs_clip)
    buf.phi_sf[r, 0] = buf.phi[r, 0]
