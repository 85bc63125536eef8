"""An environment as pure JAX functions: the step every task shares, around a task's own start
state, observation and terminations, with gymnax's interface.

A task writes, in plain ``jax.numpy`` over one episode (no buffers, no row indices, no status codes):

- ``initial(key, p, args) -> s``: the start state, drawn with ``key``, from the episode's true
  parameters ``p`` (a current the boat starts in, say);
- ``observation(s, phi, p, args) -> obs``: what the agent sees, from the state, ``phi`` with the
  true parameters, and the *nominal* parameters ``p`` (what a controller is told);
- optionally ``terminations(s, phi, args) -> {reason: bool}``: named predicates, checked in order;
- optionally ``task_params(key, p, args) -> p``: the task's own random parameters (a random
  current's amplitudes), drawn before the mismatch;
- optionally ``scale_free(s, phi, args) -> phi~``: the scale-free ``phi`` of the reward (default
  ``phi / phi_sf_scale``).

``args`` is the task's constants (a ``NamedTuple`` of numbers and arrays), part of the parameters
pytree. `FunctionalEnv` does the rest once for every task: the action's clip and force bound, the
velocity impulses, RK4 (with the stabilising law inside it in the feedback modes), the non-finite
end, the state bounds (``Task.limits``), observation noise and clip, the scale-free ``phi`` and the
reward, the time limit and gymnax's autoreset.

Everything is a pure function of arrays: ``jax.jit`` compiles it, ``jax.vmap`` batches it over
episodes, and the same code runs on a CPU or a GPU.  The precision is the caller's (float32 by
default in JAX; float64 inside ``jax.enable_x64(True)``); nothing here changes JAX's global settings.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from functools import partial
from types import ModuleType
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from gymnasium import spaces

from vnhc_gym.mechanics import functional as core

__all__ = ["Actuator", "EnvParams", "EnvState", "FunctionalEnv", "Step", "TaskFunctions"]

Array = Any  # a jax.Array

#: The reward shapes of ``EnvConfig.reward`` (see `vnhc_gym.envs.config.REWARDS`).
REWARD_SHAPES = ("raw", "bounded", "reciprocal")
FEEDBACK = core.FEEDBACK_MODES


@dataclass(frozen=True, eq=False)
class TaskFunctions:
    """A task's own pure functions and the declarations the shared step reads (hashable by identity,
    so that it can be a static argument of ``jax.jit``).

    Attributes
    ----------
    name : str
        The task's registry name (for errors).
    system : module
        The printed system (`vnhc_gym.systems.printed`): ``drift``, ``input_fields``, ``phi``, ...
    initial, observation : callable
        See the module's docstring.
    terminations, task_params, scale_free : callable or None
        See the module's docstring.
    reasons : tuple of str
        Termination reasons by status: status ``1 + i`` is ``reasons[i]``; ``reasons[0]`` is
        ``"non_finite_state"``, then the task's own (the keys of ``terminations``, in order), then
        those only the state bounds name.
    limits : tuple of (str, int)
        ``(reason, index)``: the episode ends when ``|s[index]|`` exceeds the bound of the same
        position in `EnvParams.limit_bounds`.
    impulse_mask : tuple of float
        Weights of the velocity entries that impulses kick.
    uncertain : tuple of bool
        Per parameter: whether the mismatch perturbs it.
    obs_dim : int
    controller_inputs : callable or None
        ``controller_inputs(obs, p, args) -> (s, p_controller)``: the state and parameters of the
        controller's model read back from an observation (the model-based controllers' view).
    controller_system : module or None
        The controller's model as printed functions (the environment's own system unless the task's
        controllers run a model of their own), and its ``controller_singular_tol``.
    unmodelled : callable or None
        ``unmodelled(s, p, c, args) -> (n,)``: the accelerations of the forces the nominal model lacks,
        with the episode's coefficients ``c`` (the ``unmodelled`` scenario).
    unmodelled_ranges : tuple of (float, float)
        The range each coefficient of ``unmodelled`` is drawn from (uniformly, per episode, then
        times ``EnvParams.unmodelled_scale``).
    """

    name: str
    system: ModuleType
    initial: Callable[..., Array]
    observation: Callable[..., Array]
    terminations: Callable[..., Mapping[str, Array]] | None = None
    task_params: Callable[..., Array] | None = None
    scale_free: Callable[..., Array] | None = None
    reasons: tuple[str, ...] = ("non_finite_state",)
    limits: tuple[tuple[str, int], ...] = ()
    impulse_mask: tuple[float, ...] = ()
    uncertain: tuple[bool, ...] = ()
    obs_dim: int = 0
    controller_inputs: Callable[..., tuple[Array, Array]] | None = None
    controller_system: ModuleType | None = None
    controller_singular_tol: float | None = None
    unmodelled: Callable[..., Array] | None = None
    unmodelled_ranges: tuple[tuple[float, float], ...] = ()


class EnvParams(NamedTuple):
    """What an episode is drawn and scored with (a pytree: change it without recompiling).

    Names and meanings as in the environments' cards (`vnhc_gym.envs.config.EnvConfig`).
    """

    nominal: Array  #: (n_params,) the parameters a controller is told
    force_bound: Array  #: (m,) force (N, N m) of action 1 per control
    dt: Array  #: control period (s)
    param_mismatch: Array
    obs_noise: Array
    obs_clip: Array
    impulse_prob: Array
    impulse_scale: Array
    reward_sigma: Array
    phi_scale: Array
    phi_sf_scale: Array
    action_cost: Array
    reward_clip: Array
    gains: Array  #: the in-loop law's gains (the feedback modes)
    limit_bounds: Array  #: (L,) the state bounds of ``TaskFunctions.limits``
    args: Any  #: the task's constants
    delay_range: Array = 0.0  #: (2,) the delay's range (control periods)
    lag_range: Array = 0.0  #: (2,) the actuator time constant's range (s)
    unmodelled_scale: Array = 0.0  #: scale of the task's unmodelled forces
    redraw: Array = 0.0  #: 1: the hidden quantities are drawn again once, mid-episode
    max_steps_in_episode: int = 400


class Actuator(NamedTuple):
    """What an episode whose model is wrong in structure hides from the controller.

    ``hidden`` holds two draws of ``(delay, time constant, unmodelled coefficients...)``: the first
    is in force before step ``switch_at``, the second from it on (``switch_at`` past the episode's
    end: one draw all along).
    """

    queue: Array  #: (Q, m) the commands not yet applied, the newest first (Q: the largest delay)
    lagged: Array  #: (m,) the actuator's force (its state under a lag)
    hidden: Array  #: (2, 2 + k) the two draws
    switch_at: Array  #: the step from which the second draw is in force


class EnvState(NamedTuple):
    """One episode (gymnax's ``EnvState``: the environment's whole memory)."""

    s: Array  #: (2n,) the physical state ``(q, qd)``
    p: Array  #: (n_params,) the episode's true parameters
    p_nominal: Array  #: (n_params,) what a controller is told (the task's own random parameters in it)
    obs: Array  #: the last observation (kept when a new one is not finite)
    time: Array  #: steps since the episode's start
    actuator: Any = None  #: an `Actuator` where the episode hides structure (None: none)
    history: Any = None  #: the observations before ``obs`` that an environment with memory shows (None: none)


class Step(NamedTuple):
    """What `FunctionalEnv.transition` returns beside the new state."""

    obs: Array
    reward: Array
    terminated: Array
    status: Array  #: 0, or ``1 + i`` for reason ``i`` of ``TaskFunctions.reasons``
    phi: Array  #: (m,) with the true parameters, at the new state
    abs_phi: Array  #: mean |phi|
    abs_phi_sf: Array  #: mean |phi~|
    force: Array  #: (m,) the applied force, averaged over the substeps
    s_reached: Array  #: the state RK4 reached (not finite when the episode ended as non-finite)


@dataclass(frozen=True, eq=False)
class FunctionalEnv:
    """A task's environment as pure functions, with gymnax's interface.

    ``reset(key, params) -> (obs, state)`` and ``step(key, state, action, params) -> (obs, state,
    reward, terminated, truncated, info)`` with an automatic reset at an episode's end (the
    episode's last observation in ``info["final_observation"]``), as in gymnax; `transition` is the
    step without the reset, for the Gymnasium environments.

    Parameters
    ----------
    task : TaskFunctions
    substeps : int
        RK4 steps per control period (a loop count: fixed at compile time).
    reward : {"raw", "bounded", "reciprocal"}
    feedback : {"open", "continuous", "sampled"}
        ``"open"``: the action's force alone; ``"continuous"``: the law (nominal parameters, true
        state) added at every RK4 stage; ``"sampled"``: added once per period and held.  The total
        is clipped to the force bound.
    default_params : EnvParams
    delay_slots : int
        Commands held for a delay (the largest delay: an array size, fixed at compile time).
    structural : bool
        Whether episodes hide structure (`Actuator`); False leaves the step as the model has it.
        The in-loop law of the feedback modes acts on the state directly, past the actuator.
    """

    task: TaskFunctions
    default_params: EnvParams
    substeps: int = 1
    reward: str = "bounded"
    feedback: str = "open"
    delay_slots: int = 0
    structural: bool = False

    def __post_init__(self) -> None:
        if self.reward not in REWARD_SHAPES:
            raise ValueError(f"reward must be one of {list(REWARD_SHAPES)}, got {self.reward!r}")
        if self.feedback not in FEEDBACK:
            raise ValueError(f"feedback must be one of {list(FEEDBACK)}, got {self.feedback!r}")

    # ------------------------------------------------------------------ gymnax's interface
    @property
    def name(self) -> str:
        return self.task.name

    @property
    def num_actions(self) -> int:
        return int(self.task.system.M)

    @property
    def obs_dim(self) -> int:
        return int(self.task.obs_dim)

    def check_action(self, action: Array) -> None:
        """``ValueError`` naming the task if one episode's action is not ``(num_actions,)`` (checked
        while tracing: a wrong shape would otherwise broadcast against the force bound)."""
        if jnp.shape(action) != (self.num_actions,):
            raise ValueError(f"task {self.task.name!r}: an action of one episode has shape ({self.num_actions},), "
                             f"got {jnp.shape(action)}")

    def action_space(self, params: EnvParams | None = None) -> spaces.Box:
        """``Box(-1, 1, (m,))``: the force is ``force_bound * action``."""
        return spaces.Box(-1.0, 1.0, (self.num_actions,), np.float32)

    def observation_space(self, params: EnvParams | None = None) -> spaces.Box:
        """``Box(-obs_clip, obs_clip, (obs_dim,))``."""
        clip = np.float32((params or self.default_params).obs_clip)
        return spaces.Box(-clip, clip, (self.task.obs_dim,), np.float32)

    @partial(jax.jit, static_argnums=0)
    def reset(self, key: Array, params: EnvParams | None = None) -> tuple[Array, EnvState]:
        """A new episode drawn with ``key``: its observation and state."""
        return self.initial(key, self.default_params if params is None else params)

    @partial(jax.jit, static_argnums=0)
    def step(self, key: Array, state: EnvState, action: Array, params: EnvParams | None = None
             ) -> tuple[Array, EnvState, Array, Array, Array, dict[str, Array]]:
        """One control period, then a new episode if this one ended (gymnax's autoreset)."""
        params = self.default_params if params is None else params
        key_step, key_reset = jax.random.split(key)
        new, out = self.transition(key_step, state, action, params)
        truncated = jnp.logical_and(~out.terminated, new.time >= params.max_steps_in_episode)
        done = jnp.logical_or(out.terminated, truncated)
        obs, state = self._autoreset(done, key_reset, out.obs, new, params)
        info = {"phi": out.phi, "abs_phi": out.abs_phi, "abs_phi_sf": out.abs_phi_sf, "status": out.status,
                "force": out.force, "final_observation": out.obs, "terminated": out.terminated,
                "truncated": truncated}
        return obs, state, out.reward, out.terminated, truncated, info

    @partial(jax.jit, static_argnums=0)
    def step_batch(self, key: Array, state: EnvState, action: Array, params: EnvParams | None = None
                   ) -> tuple[Array, EnvState, Array, Array, Array, dict[str, Array]]:
        """`step` for a batch of episodes (``state`` and ``action`` with a leading axis): row ``i``
        goes on with key ``split(key_step, n)[i]`` and, if it ended, starts the episode drawn with
        ``split(key_reset, n)[i]`` (``key_step, key_reset = split(key)``).  New episodes are drawn
        only for the rows that ended (`_reset_rows`), as ``jax.vmap(step)`` does.
        """
        params = self.default_params if params is None else params
        n = action.shape[0]
        key_step, key_reset = jax.random.split(key)
        new, out = jax.vmap(self.transition, in_axes=(0, 0, 0, None))(jax.random.split(key_step, n), state, action,
                                                                     params)
        truncated = jnp.logical_and(~out.terminated, new.time >= params.max_steps_in_episode)
        done = jnp.logical_or(out.terminated, truncated)
        obs, state = self._reset_rows(done, jax.random.split(key_reset, n), out.obs, new, params)
        info = {"phi": out.phi, "abs_phi": out.abs_phi, "abs_phi_sf": out.abs_phi_sf, "status": out.status,
                "force": out.force, "final_observation": out.obs, "terminated": out.terminated,
                "truncated": truncated}
        return obs, state, out.reward, out.terminated, truncated, info

    # ------------------------------------------------------------------ the automatic reset
    def _autoreset(self, done: Array, key: Array, obs: Array, new: EnvState, params: EnvParams
                   ) -> tuple[Array, EnvState]:
        """The episode drawn with ``key`` where ``done``, else ``(obs, new)``.

        One episode draws its new start on every step and keeps it only where it ended.  Under
        ``jax.vmap`` (the batching rule below), that would draw a start for every row on every
        step, which costs as much as the step itself (threefry draws and the task's start state);
        the rule draws starts only for the rows that ended (`_reset_rows`), with the same keys, so
        every row gets the same numbers as one episode stepped alone.
        """

        @jax.custom_batching.custom_vmap
        def select(done: Array, key: Array, obs: Array, new: EnvState, params: EnvParams) -> tuple[Array, EnvState]:
            obs_reset, state_reset = self.initial(key, params)
            return (jnp.where(done, obs_reset, obs),
                    jax.tree.map(lambda a, b: jnp.where(done, a, b), state_reset, new))

        @select.def_vmap
        def select_rows(axis_size: int, in_batched: list[Any], done: Array, key: Array, obs: Array, new: EnvState,
                        params: EnvParams) -> tuple[tuple[Array, EnvState], Any]:
            if any(jax.tree.leaves(in_batched[4])):
                # Parameters per row (a batch over scenarios): every row draws its own start.
                axes = jax.tree.map(lambda b: 0 if b else None, tuple(in_batched))
                out = jax.vmap(select.fun, in_axes=axes)(done, key, obs, new, params)
            else:
                def rows(x: Array, batched: bool) -> Array:
                    return x if batched else jnp.broadcast_to(x, (axis_size, *x.shape))

                done, key, obs, new = (jax.tree.map(rows, a, b) for a, b in zip((done, key, obs, new), in_batched[:4],
                                                                                strict=True))
                out = self._reset_rows(done, key, obs, new, params)
            return out, jax.tree.map(lambda _: True, out)

        return select(done, key, obs, new, params)

    def _reset_rows(self, done: Array, keys: Array, obs: Array, new: EnvState, params: EnvParams
                    ) -> tuple[Array, EnvState]:
        """Row ``i`` of ``(obs, new)``, or the episode drawn with ``keys[i]`` where ``done[i]``.

        The rows that ended are gathered in chunks of an eighth of the batch (a few percent of the
        rows end on a step with random actions), and a chunk's starts are drawn and scattered back
        while rows remain: one chunk on most steps instead of a start for every row.  A
        ``while_loop``, not a ``cond`` between a few rows and all of them: under an outer
        ``jax.vmap`` (seeds side by side) a ``cond`` would run both branches.
        """
        n = done.shape[0]
        chunk = max(1, -(-n // 8))
        chunks = -(-n // chunk)
        # The rows that ended first, in order; the padding (index n) is out of bounds and dropped.
        idx = jnp.nonzero(done, size=chunks * chunk, fill_value=n)[0]
        count = jnp.sum(done, dtype=jnp.int32)

        def draw(carry: tuple[Array, Array, EnvState]) -> tuple[Array, Array, EnvState]:
            c, obs, state = carry
            rows = jax.lax.dynamic_slice_in_dim(idx, c * chunk, chunk)
            o, s = jax.vmap(self.initial, in_axes=(0, None))(keys[jnp.minimum(rows, n - 1)], params)
            put = partial(_put_rows, rows)
            return c + 1, put(obs, o), jax.tree.map(put, state, s)

        _, obs, state = jax.lax.while_loop(lambda carry: carry[0] * chunk < count, draw,
                                           (jnp.zeros((), jnp.int32), obs, new))
        return obs, state

    # ------------------------------------------------------------------ the shared step
    def initial(self, key: Array, params: EnvParams) -> tuple[Array, EnvState]:
        """A new episode: the task's own random parameters, the mismatch of the uncertain ones, the
        task's start state, then its observation (with noise)."""
        t = self.task
        k_task, k_mismatch, k_state, k_noise = jax.random.split(key, 4)
        nominal = jnp.asarray(params.nominal)
        if t.task_params is not None:
            nominal = t.task_params(k_task, nominal, params.args)

        def mismatch(k: Array) -> Array:
            factor = 1.0 + params.param_mismatch * jax.random.uniform(k, nominal.shape, nominal.dtype, -1.0, 1.0)
            return jnp.where(jnp.asarray(t.uncertain, dtype=bool), nominal * factor, nominal)

        p = _when(params.param_mismatch > 0, mismatch, lambda k: nominal, k_mismatch)
        s = t.initial(k_state, p, params.args)
        obs = self._observe(k_noise, s, t.system.phi(s, p), nominal, params)
        # Folded in, not split: the episodes of the other scenarios keep their random numbers.
        actuator = self._hidden(jax.random.fold_in(key, 1), s.dtype, params) if self.structural else None
        return obs, EnvState(s=s, p=p, p_nominal=nominal, obs=obs, time=jnp.zeros((), jnp.int32), actuator=actuator)

    @property
    def queue_length(self) -> int:
        """Commands an episode holds: the largest delay, and at least one (no empty arrays)."""
        return max(1, self.delay_slots)

    @property
    def n_hidden(self) -> int:
        """Entries of one draw of the hidden quantities: the delay, the time constant, the coefficients."""
        return 2 + len(self.task.unmodelled_ranges)

    def _hidden(self, key: Array, dtype: Any, params: EnvParams) -> Actuator:
        """The episode's two draws of its hidden quantities, an empty queue and an actuator at rest."""
        k_delay, k_lag, k_coef, k_switch = jax.random.split(key, 4)
        low, high = jnp.asarray(params.delay_range, dtype)[0], jnp.asarray(params.delay_range, dtype)[1]
        delay = jnp.minimum(jnp.floor(low + (high - low + 1.0) * jax.random.uniform(k_delay, (2,), dtype)), high)
        lag_low, lag_high = jnp.asarray(params.lag_range, dtype)[0], jnp.asarray(params.lag_range, dtype)[1]
        log_tau = jax.random.uniform(k_lag, (2,), dtype, jnp.log(jnp.maximum(lag_low, 1e-12)),
                                     jnp.log(jnp.maximum(lag_high, 1e-12)))
        tau = jnp.where(lag_high > 0, jnp.exp(log_tau), 0.0)
        drawn = [delay[:, None], tau[:, None]]
        if self.task.unmodelled_ranges:  # no empty arrays in a program (XLA's cache has crashed on them)
            ranges = np.asarray(self.task.unmodelled_ranges, dtype=np.float64)
            drawn.append(params.unmodelled_scale * (ranges[:, 0] + (ranges[:, 1] - ranges[:, 0])
                                                    * jax.random.uniform(k_coef, (2, ranges.shape[0]), dtype)))
        hidden = jnp.concatenate(drawn, axis=1)
        steps = params.max_steps_in_episode
        switch = jnp.where(params.redraw > 0, jnp.floor(steps * jax.random.uniform(k_switch, (), dtype, 0.25, 0.75)),
                           steps + 1.0)
        m = self.num_actions
        return Actuator(queue=jnp.zeros((self.queue_length, m), dtype), lagged=jnp.zeros(m, dtype),
                        hidden=hidden.astype(dtype), switch_at=switch.astype(dtype))

    def hidden_now(self, state: EnvState) -> Array:
        """The hidden quantities in force at the episode's step ``state.time``: ``(delay, time
        constant, coefficients...)``."""
        act = state.actuator
        return jnp.where(state.time >= act.switch_at, act.hidden[1], act.hidden[0])

    def true_system(self, hidden: Array, params: EnvParams) -> Any:
        """The episode's true dynamics: the printed system with the unmodelled forces of ``hidden``'s
        coefficients (the system itself where the task has none)."""
        t = self.task
        if not self.structural or t.unmodelled is None:
            return t.system
        return core.WithForces(t.system, partial(_unmodelled, t.unmodelled, hidden[2:], params.args))

    def transition(self, key: Array, state: EnvState, action: Array, params: EnvParams) -> tuple[EnvState, Step]:
        """One control period of one episode, without the reset (see `step`)."""
        self.check_action(action)
        t = self.task
        system = t.system
        n = system.N
        k_kick, k_noise = jax.random.split(key)
        a = jnp.clip(jnp.asarray(action, dtype=state.s.dtype), -1.0, 1.0)
        actuator = state.actuator
        if self.structural:
            hidden = self.hidden_now(state)
            force, actuator = actuate(actuator, a * params.force_bound, hidden, params.dt)
            s_next, force = self._advance(state, force, params, self.true_system(hidden, params))
        else:
            s_next, force = self._advance(state, a * params.force_bound, params, system)

        def kick(k: Array) -> Array:
            """A velocity impulse with probability impulse_prob, on the entries impulse_mask weights."""
            k_when, k_size = jax.random.split(k)
            size = params.impulse_scale * jax.random.normal(k_size, (n,), state.s.dtype) * jnp.asarray(t.impulse_mask)
            return jnp.where(jax.random.uniform(k_when, (), state.s.dtype) < params.impulse_prob, size, 0.0)

        s_next = s_next.at[n:].add(_when(params.impulse_prob > 0, kick, lambda k: jnp.zeros(n, state.s.dtype),
                                         k_kick))
        finite = jnp.all(jnp.isfinite(s_next))
        s = jnp.where(finite, s_next, state.s)  # a non-finite state ends the episode; the last finite one stays
        phi = system.phi(s, state.p)
        phi_sf = self._scale_free(s, phi, params)
        obs = self._observe(k_noise, s, phi, state.p_nominal, params)
        abs_phi = jnp.mean(jnp.abs(phi))
        abs_phi_sf = jnp.mean(jnp.abs(phi_sf))
        nonfinite = ~finite | ~jnp.isfinite(abs_phi) | ~jnp.all(jnp.isfinite(obs))
        status = jnp.where(nonfinite, 1, self._status(s, phi, params))
        reward = self._reward(abs_phi, abs_phi_sf, a, nonfinite, params)
        obs = jnp.where(nonfinite, state.obs, obs)
        new = EnvState(s=s, p=state.p, p_nominal=state.p_nominal, obs=obs, time=state.time + 1, actuator=actuator)
        return new, Step(obs=obs, reward=reward, terminated=status > 0, status=status, phi=phi, abs_phi=abs_phi,
                         abs_phi_sf=abs_phi_sf, force=force, s_reached=s_next)

    def _advance(self, state: EnvState, force: Array, params: EnvParams, system: Any) -> tuple[Array, Array]:
        """RK4 of ``system`` over ``dt`` with the action's force (and the law, in the feedback modes),
        the total clipped to the force bound; the applied force averaged over the substeps."""
        bound = params.force_bound
        x, applied, _ = core.rk4_step_controlled(
            system, state.s, state.p, force, params.dt, self.substeps, feedback=self.feedback,
            p_law=state.p_nominal, gains=params.gains, lower=-bound, upper=bound)
        return x, applied

    def _scale_free(self, s: Array, phi: Array, params: EnvParams) -> Array:
        if self.task.scale_free is not None:
            return self.task.scale_free(s, phi, params.args)
        return phi / params.phi_sf_scale

    def _observe(self, key: Array, s: Array, phi: Array, nominal: Array, params: EnvParams) -> Array:
        """The task's observation with Gaussian noise, clipped."""
        obs = jnp.asarray(self.task.observation(s, phi, nominal, params.args), dtype=s.dtype)
        obs = _when(params.obs_noise > 0, lambda k: obs + params.obs_noise * jax.random.normal(k, obs.shape, obs.dtype),
                    lambda k: obs, key)
        return jnp.clip(obs, -params.obs_clip, params.obs_clip)

    def _status(self, s: Array, phi: Array, params: EnvParams) -> Array:
        """0, or ``1 + i`` for the first reason ``i`` that holds: the task's predicates in order, then
        the state bounds in order."""
        t = self.task
        checks: list[tuple[str, Array]] = []
        if t.terminations is not None:
            checks += list(t.terminations(s, phi, params.args).items())
        checks += [(reason, jnp.abs(s[i]) > params.limit_bounds[k]) for k, (reason, i) in enumerate(t.limits)]
        status = jnp.zeros((), jnp.int32)
        for reason, hit in reversed(checks):  # the first that holds wins
            status = jnp.where(hit, 1 + t.reasons.index(reason), status)
        return status

    def _reward(self, abs_phi: Array, abs_phi_sf: Array, a: Array, nonfinite: Array, params: EnvParams) -> Array:
        """The reward of ``EnvConfig.reward``; 0 (``"raw"``: ``-reward_clip``) at a non-finite end."""
        cost = params.action_cost * jnp.mean(a * a)
        if self.reward == "raw":
            r = -abs_phi / params.phi_scale - cost
            r = jnp.where(nonfinite | jnp.isnan(r), -params.reward_clip, r)
            return jnp.clip(r, -params.reward_clip, 0.0)
        x = abs_phi_sf / params.reward_sigma
        r = (jnp.exp(-x) if self.reward == "bounded" else 1.0 / (1.0 + x)) - cost
        return jnp.clip(jnp.where(nonfinite | jnp.isnan(r), 0.0, r), 0.0, 1.0)


def actuate(actuator: Actuator, command: Array, hidden: Array, dt: Array) -> tuple[Array, Actuator]:
    """The force an actuator applies over one period, and its memory after it.

    The command joins the queue; the one commanded ``d = hidden[0]`` periods ago (0 before the start)
    drives the lag of time constant ``hidden[1]`` (`lag`).
    """
    full = jnp.concatenate([command[None], actuator.queue])
    delayed = full[jnp.clip(hidden[0], 0, full.shape[0] - 1).astype(jnp.int32)]
    mean, lagged = lag(actuator.lagged, delayed, hidden[1], dt)
    return mean, actuator._replace(queue=full[:-1], lagged=lagged)


def lag(z: Array, command: Array, tau: Array, dt: Array) -> tuple[Array, Array]:
    """A first-order actuator over one period: ``(mean force, force at the end)``.

    Its force ``z`` relaxes towards the held command as ``exp(-t / tau)``; the period's force is
    ``z``'s mean over the period, ``w z + (1 - w) command`` with ``w = tau / dt (1 - exp(-dt /
    tau))``.  ``tau = 0``: no lag (the command itself).
    """
    w, decay = lag_weights(tau, dt)
    return w * z + (1.0 - w) * command, command + (z - command) * decay


def lag_weights(tau: Array, dt: Array) -> tuple[Array, Array]:
    """``(w, exp(-dt / tau))`` of `lag` (both 0 for ``tau = 0``)."""
    lagging = tau > 0
    ratio = dt / jnp.where(lagging, tau, 1.0)
    return jnp.where(lagging, -jnp.expm1(-ratio) / ratio, 0.0), jnp.where(lagging, jnp.exp(-ratio), 0.0)


def _unmodelled(fn: Callable[..., Array], coef: Array, args: Any, s: Array, p: Array) -> Array:
    return fn(s, p, coef, args)


def _put_rows(rows: Array, dest: Array, values: Array) -> Array:
    """``dest`` with ``dest[rows[j]] = values[j]``; rows out of bounds are dropped."""
    return dest.at[rows].set(values.astype(dest.dtype), mode="drop")


def _when(pred: Array, draw: Callable[[Array], Array], otherwise: Callable[[Array], Array], key: Array) -> Array:
    """``draw(key)`` if ``pred`` else ``otherwise(key)``: random draws only where a scenario has them.

    Why a ``lax.cond``: the predicate is a parameter, the same for every episode of a batch, so
    under ``jax.vmap`` it stays a branch and a scenario without noise draws no random numbers (the
    threefry draws cost more than the physics of a step on a CPU).
    """
    return jax.lax.cond(pred, draw, otherwise, key)
