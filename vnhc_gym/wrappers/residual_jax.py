"""Residual learning on the pure-JAX environment (the compiled backend's residual PPO and SAC): the
counterpart of [`ResidualVectorAction`][vnhc_gym.wrappers.ResidualVectorAction].

The environment receives ``clip(base(obs) + scale * clip(a, -1, 1), -1, 1)``, where ``base`` acts on
the observation the agent saw (`law_base`: the geometric law, plain or sampled-data, on the state the
task's ``controller_inputs`` reads back), so an agent whose action is 0 *is* the base.
With ``observe_base`` the agent sees ``(obs, base(obs))``, or ``(obs, belief, base(obs))`` for a
base with a memory, as `ResidualVectorAction` shows them.  A base with a memory (`kalman_base`: the
law on an extended Kalman filter's estimate, as [`KalmanController`][vnhc_gym.baselines.KalmanController]
computes it) is a `MemoryBase`: its memory rides in the episode's state (`EnvState.history`), starts
at the episode's first observation and is told the force applied at every step.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

import jax.numpy as jnp

from vnhc_gym.baselines.kalman import EKF, FilterNoise
from vnhc_gym.envs.config import check_number
from vnhc_gym.envs.functional import EnvParams, EnvState, FunctionalEnv, Step
from vnhc_gym.mechanics import functional as core
from vnhc_gym.tasks.base import Task

__all__ = ["BASES", "MemoryBase", "ResidualEnv", "kalman_base", "law_base"]

Array = Any  # a jax.Array
#: ``base(obs, p_nominal, params) -> action`` in ``[-1, 1]``: the base's action on one observation.
Base = Callable[[Array, Array, EnvParams], Array]
#: The classical baselines a compiled residual runs on (by `make_classical`'s names).
BASES = ("law", "tuned_law", "kalman")


class MemoryBase(NamedTuple):
    """A base with a memory of the episode (pure functions; the memory is a pytree).

    ``start(obs, p_nominal, params) -> memory`` at an episode's first observation;
    ``update(memory, obs, applied, p_nominal, params) -> memory`` at each next one, told the action
    the environment applied since (in ``[-1, 1]``); ``act(memory, p_nominal, params) -> action``;
    ``belief(memory, obs, params) -> observation``: what the base believes it would have seen
    without noise (as [`Policy.belief`][vnhc_gym.baselines.Policy.belief]; ``obs`` where its frame
    holds no value), which a residual agent sees beside the observation.
    """

    start: Callable[[Array, Array, EnvParams], Any]
    update: Callable[[Any, Array, Array, Array, EnvParams], Any]
    act: Callable[[Any, Array, EnvParams], Array]
    belief: Callable[[Any, Array, EnvParams], Array]


def _law_action(env: FunctionalEnv, gain: Any, variant: str, iters: int) -> Callable[[Array, Array, EnvParams], Array]:
    """``action(s, p, params)``: the law of ``variant`` at the controller state ``s`` and parameters
    ``p``, divided by the force bound, clipped to ``[-1, 1]`` (0 where not finite)."""
    if variant not in ("plain", "sampled"):
        raise ValueError(f"variant must be 'plain' or 'sampled', got {variant!r}")
    t = env.task
    if t.controller_system is None:
        raise ValueError(f"task {t.name!r}: its module defines no controller_inputs, so the law cannot read "
                         f"its observations")
    system, tol = t.controller_system, t.controller_singular_tol

    def action(s: Array, p: Array, params: EnvParams) -> Array:
        u, singular = core.checked_law(system, s, p, gain, tol)
        if variant == "sampled":
            us, _ = core.sampled_law(system, s, p, params.dt, gain, env.substeps, iters)
            u = jnp.where(singular | ~jnp.all(jnp.isfinite(us)), u, us)
        a = u / params.force_bound
        return jnp.clip(jnp.where(jnp.isfinite(a), a, 0.0), -1.0, 1.0)

    return action


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
    action = _law_action(env, gain, variant, iters)
    chart = env.task.controller_inputs
    if chart is None:
        raise ValueError(f"task {env.task.name!r}: its module defines no controller_inputs, so the law cannot "
                         f"read its observations")

    def base(obs: Array, p_nominal: Array, params: EnvParams) -> Array:
        s, p = chart(obs, p_nominal, params.args)
        return action(s, p, params)

    return base


def kalman_base(env: FunctionalEnv, task: Task, gain: Any = 5.0, variant: str = "plain", q: float = 1.0,
                q_params: float = 0.03, iters: int = 4) -> MemoryBase:
    """The law of ``variant`` on an extended Kalman filter's estimate (`vnhc_gym.baselines.kalman.EKF`),
    as [`KalmanController`][vnhc_gym.baselines.KalmanController] computes it: the filter starts at an
    episode's first observation, predicts each period with the force applied (``applied`` times the
    force bound) and corrects with the new observation, with the environment's ``obs_noise``.

    ``task`` is the configured task of ``env`` (``gym.make(...).unwrapped.task``): the filter's model,
    measurement model and frame.
    """
    ekf = EKF.of(task)
    q, q_params = check_number("q", q, low=0.0, high=1e6), check_number("q_params", q_params, low=0.0, high=1e6)
    action = _law_action(env, gain, variant, iters)

    def start(obs: Array, p_nominal: Array, params: EnvParams) -> Any:
        return ekf.start(obs, p_nominal, params.args, params.obs_noise)

    def update(memory: Any, obs: Array, applied: Array, p_nominal: Array, params: EnvParams) -> Any:
        u = jnp.clip(applied, -1.0, 1.0) * params.force_bound
        return ekf.update(memory, obs, u, p_nominal, params.args, FilterNoise(params.dt, params.obs_noise, q, q_params))

    def act(memory: Any, p_nominal: Array, params: EnvParams) -> Array:
        s, p = ekf.estimate(memory)
        return action(s, p, params)

    def belief(memory: Any, obs: Array, params: EnvParams) -> Array:
        s, p = ekf.estimate(memory)
        seen = ekf.seen(s, p, p, params.args)
        return jnp.where(jnp.isfinite(seen), jnp.clip(seen, -params.obs_clip, params.obs_clip), obs)

    return MemoryBase(start=start, update=update, act=act, belief=belief)


@dataclass(frozen=True, eq=False)
class ResidualEnv(FunctionalEnv):
    """``env`` with a learned residual on top of ``base`` (gymnax's interface, as `FunctionalEnv`).

    Build it with `ResidualEnv.around`.  ``scale`` is the largest residual as a fraction of the
    action range; ``observe_base`` appends the base's action to the observation.  Only `initial` and
    `transition` differ from the plain environment's, so its `step`, `step_batch` and automatic
    reset carry the residual through unchanged: a restarted row is seen with its base's action, and
    ``info["final_observation"]`` is the last observation seen.
    """

    base: Base | MemoryBase | None = None
    scale: float = 0.2
    observe_base: bool = False

    @classmethod
    def around(cls, env: FunctionalEnv, base: Base | MemoryBase, scale: float = 0.2,
               observe_base: bool = False) -> ResidualEnv:
        if not 0.0 <= float(scale) <= 1.0:
            raise ValueError(f"scale must be in [0, 1], got {scale!r}")
        return cls(task=env.task, default_params=env.default_params, substeps=env.substeps, reward=env.reward,
                   feedback=env.feedback, base=base, scale=float(scale), observe_base=bool(observe_base))

    @property
    def obs_dim(self) -> int:
        if not self.observe_base:
            return int(self.task.obs_dim)
        belief = int(self.task.obs_dim) if isinstance(self.base, MemoryBase) else 0
        return int(self.task.obs_dim) + belief + self.num_actions

    def _base(self, state: EnvState, params: EnvParams) -> Array:
        """The base's action at the episode's last observation (and memory)."""
        if self.base is None:
            raise ValueError("ResidualEnv has no base: build it with ResidualEnv.around(env, base)")
        if isinstance(self.base, MemoryBase):
            a = self.base.act(state.history, state.p_nominal, params)
        else:
            a = self.base(state.obs, state.p_nominal, params)
        return a.astype(state.obs.dtype)

    def _seen(self, state: EnvState, params: EnvParams) -> Array:
        """What the agent sees of the episode's last observation: with ``observe_base``, the base's
        belief (a base with a memory) and action appended, as `ResidualVectorAction` shows them."""
        if not self.observe_base:
            return state.obs
        parts = [state.obs, self._base(state, params)]
        if isinstance(self.base, MemoryBase):
            parts.insert(1, self.base.belief(state.history, state.obs, params).astype(state.obs.dtype))
        return jnp.concatenate(parts)

    def _applied(self, state: EnvState, action: Array, params: EnvParams) -> Array:
        residual = self.scale * jnp.clip(jnp.asarray(action, state.obs.dtype), -1.0, 1.0)
        return jnp.clip(self._base(state, params) + residual, -1.0, 1.0)

    def initial(self, key: Array, params: EnvParams) -> tuple[Array, EnvState]:
        obs, state = super().initial(key, params)
        if isinstance(self.base, MemoryBase):
            state = state._replace(history=self.base.start(obs, state.p_nominal, params))
        return self._seen(state, params), state

    def transition(self, key: Array, state: EnvState, action: Array, params: EnvParams) -> tuple[EnvState, Step]:
        """One period with the base's action on the last observation plus the scaled residual."""
        self.check_action(action)
        applied = self._applied(state, action, params)
        new, out = super().transition(key, state, applied, params)
        if isinstance(self.base, MemoryBase):
            new = new._replace(history=self.base.update(state.history, new.obs, applied, new.p_nominal, params))
        return new, out._replace(obs=self._seen(new, params))
