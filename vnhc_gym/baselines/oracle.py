"""The headroom reference: the sampled-data law on the true state and the episode's true parameters.

[`OracleController`][vnhc_gym.baselines.OracleController] is not a controller anyone could field: it
ignores the observation and reads the environment's own state and true parameters (so no observation
noise, no model mismatch, no current known only locally).  On those it applies the sampled-data
variant of the geometric law
([`vnhc_gym.mechanics.sampled_control`][vnhc_gym.mechanics.sampled_control]): the held force that
makes ``phi`` after one control period of the environment's own RK4 step map equal
``exp(-K dt) phi``, clipped to the force bound.  What it cannot undo is what nobody can: the force
bound and unforeseeable velocity kicks.  The distance between it and a cell's best classical
baseline says how much a better controller, learned or not, could still gain there.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from vnhc_gym.baselines.geometric import GeometricController
from vnhc_gym.mechanics import sampled_control

__all__ = ["OracleController"]

Array = NDArray[np.float64]

#: Default gain: ``exp(-k dt)`` = 0.14 per 0.05 s control period.
ORACLE_GAIN = 40.0


def _batch_of(env: Any) -> Any:
    """The `vnhc_gym.envs.runtime.Batch` of a vnhc_gym environment (single, wrapped or vector)."""
    obj = env
    for _ in range(64):
        batch = getattr(obj, "batch", None) or getattr(getattr(obj, "unwrapped", None), "batch", None)
        if batch is not None and hasattr(batch, "buf"):
            return batch
        obj = getattr(obj, "env", None)
        if obj is None:
            break
    raise TypeError(f"{type(env).__name__} is not a vnhc_gym environment: the oracle reads its state")


class OracleController(GeometricController):
    """The sampled-data law on the environment's true state and parameters (module docstring).

    Parameters
    ----------
    env : gymnasium Env or VectorEnv
        The vnhc_gym environment the oracle acts on; it must be the one whose observations are
        passed to [`predict`][vnhc_gym.baselines.OracleController.predict] (row ``i`` of a batch is
        sub-environment ``i``).
    gain : float or array_like, default 40
        ``diag K`` of the sampled-data law.
    iters : int, default 4
        Newton iterations.
    """

    def __init__(self, env: Any, gain: ArrayLike = ORACLE_GAIN, *, iters: int = 4) -> None:
        super().__init__(env, gain, variant="sampled", iters=iters)
        self.batch = _batch_of(env)
        self.name = "oracle"

    def __repr__(self) -> str:
        return f"OracleController({self.task.name!r}, gain={self.gain.tolist()})"

    def force(self, obs: ArrayLike) -> tuple[Array, NDArray[np.bool_]]:
        """The unsaturated force (N) for the environment's rows (the observations give only the batch size)."""
        o, _ = self.check_obs(obs)
        buf = self.batch.buf
        if o.shape[0] != buf.state.shape[0]:
            raise ValueError(f"the oracle acts on all {buf.state.shape[0]} rows of its environment at once, "
                             f"got {o.shape[0]} observations")
        model = self.task.model
        states, params = buf.state.copy(), buf.params_true.copy()
        u, singular = model.control(states, self.gain, params, on_singular="flag")
        ok = ~np.asarray(singular)
        if ok.any():
            us, _ = sampled_control(model, states[ok], params[ok], self.dt, self.gain, self.substeps, self.iters)
            u[ok] = np.where(np.isfinite(us), us, u[ok])
        return u, np.asarray(singular)
