"""The headroom reference: the sampled-data law on the true state and the episode's true dynamics.

[`OracleController`][vnhc_gym.baselines.OracleController] is not a controller anyone could field: it
ignores the observation and reads the environment's own memory: the state, the true parameters and,
where the scenario hides structure, the delay with the commands still in its queue, the actuator's
time constant and force, and the coefficients of the forces the model lacks.  On those it applies
the sampled-data variant of the geometric law
([`vnhc_gym.mechanics.sampled_control`][vnhc_gym.mechanics.sampled_control]): the held force that
makes ``phi`` after one control period of the environment's own RK4 step map equal
``exp(-K dt) phi``.  Under a delay ``d`` it predicts the state ``d`` periods on through the queued
commands and plans there (the force commanded now acts then); under a lag it commands what makes
the actuator's mean force over the period that force.  The command is clipped to the force bound.
What it cannot undo is what nobody can: the force bound and unforeseeable velocity kicks.  The
distance between it and a cell's best classical baseline says how much a better controller,
learned or not, could still gain there.
"""

from __future__ import annotations

from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from numpy.typing import ArrayLike, NDArray

from vnhc_gym.baselines.actuated import plan
from vnhc_gym.baselines.geometric import GeometricController
from vnhc_gym.baselines.policy import batch_of
from vnhc_gym.envs.functional import Actuator, EnvParams, EnvState, FunctionalEnv
from vnhc_gym.envs.runtime import function_identity as _identity

__all__ = ["OracleController", "oracle_force"]

Array = NDArray[np.float64]

#: Default gain: ``exp(-k dt)`` = 0.14 per 0.05 s control period.
ORACLE_GAIN = 40.0


def oracle_force(env: FunctionalEnv, state: EnvState, params: EnvParams, gains: Any, iters: int = 4,
                 singular_tol: float | None = None) -> tuple[Any, Any]:
    """The oracle's command (N, unclipped) for one episode, and whether the law was singular: `plan`
    on the episode's true dynamics, state, queue and actuator.

    Parameters
    ----------
    env : FunctionalEnv
        The episode's environment (its task's system, its actuator's shape).
    state : EnvState
        The episode's whole memory, the hidden structure included.
    params : EnvParams
    gains : array_like
        ``diag K`` of the sampled-data law.
    iters : int
        Newton iterations.
    singular_tol : float or None
        The law's singular test on the true system.
    """
    s = state.s
    if env.structural:
        hidden = env.hidden_now(state)
        act = state.actuator
        return plan(env.true_system(hidden, params), s, state.p, act.queue, hidden[0], act.lagged, hidden[1],
                    params.dt, env.substeps, params.force_bound, gains, iters, singular_tol)
    m = env.num_actions
    return plan(env.task.system, s, state.p, jnp.zeros((1, m), s.dtype), jnp.zeros((), s.dtype), jnp.zeros(m, s.dtype),
                jnp.zeros((), s.dtype), params.dt, env.substeps, params.force_bound, gains, iters, singular_tol)


#: The compiled, batched `oracle_force` by environment shape.
_COMPILED: dict[Any, Any] = {}


class OracleController(GeometricController):
    """The sampled-data law on the environment's true state and dynamics (module docstring).

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
        self.batch = batch_of(env)
        self.name = "oracle"

    def __repr__(self) -> str:
        return f"OracleController({self.task.name!r}, gain={self.gain.tolist()})"

    def force(self, obs: ArrayLike) -> tuple[Array, NDArray[np.bool_]]:
        """The unsaturated command (N) for the environment's rows (the observations give only the batch size)."""
        o, _ = self.check_obs(obs)
        batch = self.batch
        buf = batch.buf
        n = buf.state.shape[0]
        if o.shape[0] != n:
            raise ValueError(f"the oracle acts on all {n} rows of its environment at once, "
                             f"got {o.shape[0]} observations")
        env = batch.env
        key = (env.task.system, _identity(env.task.unmodelled), env.task.unmodelled_ranges, env.delay_slots,
               env.structural,
               env.substeps, self.task.model.singular_tol, self.iters)
        fn = _COMPILED.get(key)
        if fn is None:
            one = partial(oracle_force, env, iters=self.iters, singular_tol=self.task.model.singular_tol)
            fn = _COMPILED[key] = jax.jit(jax.vmap(one, in_axes=(0, None, None)))
        actuator = None
        if env.structural:
            m = self.act_dim
            actuator = Actuator(queue=buf.queue.reshape(n, env.queue_length, m), lagged=buf.lagged,
                                hidden=buf.hidden.reshape(n, 2, -1), switch_at=buf.switch_at[:, 0])
        state = EnvState(s=buf.state, p=buf.params_true, p_nominal=buf.params_nominal, obs=buf.obs,
                         time=buf.steps, actuator=actuator)
        with jax.enable_x64(True):
            u, singular = fn(state, batch.params, np.asarray(self.gain, dtype=np.float64))
        return np.array(u, dtype=np.float64), np.array(singular, dtype=bool)
