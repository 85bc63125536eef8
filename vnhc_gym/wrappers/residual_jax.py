"""Residual learning on the pure-JAX environment (the compiled backend's residual PPO and SAC): the
counterpart of [`ResidualVectorAction`][vnhc_gym.wrappers.ResidualVectorAction].

The environment receives ``clip(base(obs) + scale * clip(a, -1, 1), -1, 1)``, where ``base`` is a
pure function of the observation the agent saw (`law_base`: the geometric law, plain or sampled-data,
on the state the task's ``controller_inputs`` reads back), so an agent whose action is 0 *is* the base.
With ``observe_base`` the agent sees ``(obs, base(obs))``.  A base with a filter state (the Kalman
filter's) is not a pure function of the observation and is not offered here.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import jax.numpy as jnp

from vnhc_gym.envs.functional import EnvParams, EnvState, FunctionalEnv, Step
from vnhc_gym.mechanics import functional as core

__all__ = ["BASES", "ResidualEnv", "law_base"]

Array = Any  # a jax.Array
#: ``base(obs, p_nominal, params) -> action`` in ``[-1, 1]``: the base's action on one observation.
Base = Callable[[Array, Array, EnvParams], Array]
#: The classical baselines that are pure functions of the observation (by `make_classical`'s names).
BASES = ("law", "tuned_law")


def law_base(env: FunctionalEnv, gain: Any = 5.0, variant: str = "plain", iters: int = 4) -> Base:
    """The geometric law on one observation, as [`GeometricController`][vnhc_gym.baselines.GeometricController]
    computes it: the controller model's state and parameters from the task's ``controller_inputs``,
    ``u*`` (0 where the state is singular), or for ``variant="sampled"`` the sampled-data law from it
    (``iters`` Newton steps; ``u*`` where that is not finite), divided by the force bound, clipped to
    ``[-1, 1]`` (0 where not finite).

    Raises
    ------
    ValueError
        For a task whose module defines no ``controller_inputs``, or an unknown variant.
    """
    t = env.task
    if t.controller_inputs is None or t.controller_system is None:
        raise ValueError(f"task {t.name!r}: its module defines no controller_inputs, so the law cannot read "
                         f"its observations")
    if variant not in ("plain", "sampled"):
        raise ValueError(f"variant must be 'plain' or 'sampled', got {variant!r}")
    system, chart, tol = t.controller_system, t.controller_inputs, t.controller_singular_tol

    def base(obs: Array, p_nominal: Array, params: EnvParams) -> Array:
        s, p = chart(obs, p_nominal, params.args)
        u, singular = core.checked_law(system, s, p, gain, tol)
        if variant == "sampled":
            us = core.sampled_law(system, s, p, params.dt, gain, env.substeps, iters)
            u = jnp.where(singular | ~jnp.all(jnp.isfinite(us)), u, us)
        a = u / params.force_bound
        return jnp.clip(jnp.where(jnp.isfinite(a), a, 0.0), -1.0, 1.0)

    return base


@dataclass(frozen=True, eq=False)
class ResidualEnv(FunctionalEnv):
    """``env`` with a learned residual on top of ``base`` (gymnax's interface, as `FunctionalEnv`).

    Build it with `ResidualEnv.around`.  ``scale`` is the largest residual as a fraction of the
    action range; ``observe_base`` appends the base's action to the observation.  Only `initial` and
    `transition` differ from the plain environment's, so its `step`, `step_batch` and automatic
    reset carry the residual through unchanged: a restarted row is seen with its base's action, and
    ``info["final_observation"]`` is the last observation seen.
    """

    base: Base | None = None
    scale: float = 0.2
    observe_base: bool = False

    @classmethod
    def around(cls, env: FunctionalEnv, base: Base, scale: float = 0.2, observe_base: bool = False) -> ResidualEnv:
        if not 0.0 <= float(scale) <= 1.0:
            raise ValueError(f"scale must be in [0, 1], got {scale!r}")
        return cls(task=env.task, default_params=env.default_params, substeps=env.substeps, reward=env.reward,
                   feedback=env.feedback, base=base, scale=float(scale), observe_base=bool(observe_base))

    @property
    def obs_dim(self) -> int:
        return int(self.task.obs_dim) + (self.num_actions if self.observe_base else 0)

    def _base(self, obs: Array, p_nominal: Array, params: EnvParams) -> Array:
        if self.base is None:
            raise ValueError("ResidualEnv has no base: build it with ResidualEnv.around(env, base)")
        return self.base(obs, p_nominal, params).astype(obs.dtype)

    def _seen(self, obs: Array, p_nominal: Array, params: EnvParams) -> Array:
        """What the agent sees of one observation."""
        if not self.observe_base:
            return obs
        return jnp.concatenate([obs, self._base(obs, p_nominal, params)])

    def _applied(self, state: EnvState, action: Array, params: EnvParams) -> Array:
        residual = self.scale * jnp.clip(jnp.asarray(action, state.obs.dtype), -1.0, 1.0)
        return jnp.clip(self._base(state.obs, state.p_nominal, params) + residual, -1.0, 1.0)

    def initial(self, key: Array, params: EnvParams) -> tuple[Array, EnvState]:
        obs, state = super().initial(key, params)
        return self._seen(obs, state.p_nominal, params), state

    def transition(self, key: Array, state: EnvState, action: Array, params: EnvParams) -> tuple[EnvState, Step]:
        """One period with the base's action on the last observation plus the scaled residual."""
        new, out = super().transition(key, state, self._applied(state, action, params), params)
        return new, out._replace(obs=self._seen(out.obs, new.p_nominal, params))
