"""What a task is: the one definition that the environments, baselines, training and evaluation read.

A task module (``vnhc_gym/tasks/sled.py`` is one) holds, in this order:

1. its hooks' constants (a ``NamedTuple`` called ``Args``), its termination codes, and two compiled
   per-row hooks: ``draw`` (the start state of a new episode, and any random parameters of the
   task's own) and ``observe`` (the observation, and 0 or a termination code);
2. its options (a [`TaskOptions`][vnhc_gym.envs.config.TaskOptions] dataclass) and its
   [`Task`][vnhc_gym.tasks.base.Task] subclass: the mechanical system and constraint, the hooks'
   constants, the observation size, the force bounds, the termination reasons by name, and how a
   controller reads the state back from an observation;
3. the environment class with its card (a subclass of [`ConstraintEnv`][vnhc_gym.envs.env.ConstraintEnv]);
   the registry makes its native vector version.

One line in `vnhc_gym.tasks` registers it.  Everything else is common to every task and done
by the generated step and reset kernels (`vnhc_gym.envs._step_template`): the nominal
parameters and the mismatch draw, impulses, RK4, the non-finite check, the status, clipping of the
observation, observation noise, the scale-free ``phi`` (``phi / phi_sf_scale`` unless the task
writes its own) and the reward.

The hooks' signatures::

    @njit(cache=True)
    def draw(rng, r, stage, state, params, aux, args) -> None: ...

    @njit(cache=True, inline="always")
    def observe(state, phi, aux, args, obs, phi_sf) -> int: ...

``draw`` writes the row's start ``state`` with draws from ``rng`` (call ``uniform_ab(rng, r, lo, hi)``
and the other draws of [`vnhc_gym.rng`][vnhc_gym.rng]); ``params`` holds the nominal parameters, which it may
change where the task has random parameters of its own; ``aux`` holds the true model's extra
outputs at the state drawn so far (for stages after the first).  ``observe`` writes ``obs`` from the
``state``, ``phi`` (with the true parameters) and ``aux`` (with the nominal ones), may overwrite
``phi_sf``, and returns 0 or one of the codes of `Task.reasons`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict
from typing import Any, ClassVar, NamedTuple

import numpy as np
from numpy.typing import NDArray

from vnhc_gym.envs.config import EnvConfig, TaskOptions
from vnhc_gym.mechanics import ConstrainedSystem

__all__ = ["Task"]

Array = NDArray[np.float64]


class Task:
    """A virtual-constraint task configured for one environment (subclass once per task).

    A subclass defines the class attributes below (the task's definition); its constructor sets the
    instance attributes listed under Notes.

    Attributes
    ----------
    name : str
        Registry name (``"usv"``).
    Options : type of TaskOptions
        The task's own keyword arguments, with defaults, meanings and checks.
    reasons : mapping of str to int
        Termination reasons by name, with the code (>= 1) the task's ``observe`` returns for each;
        ``"non_finite_state"`` is common to every task.  Reasons that are a bound on one state
        entry are better declared as ``limits``.
    default_force_bound : float or tuple of float
        Force of action 1 per control (one number: the same for every control) when
        ``force_bound`` is not given, in ``force_units``.
    force_units : str or tuple of str
        Units of each control (``"N"``, ``("N", "N m")``).
    default_impulse_scale : float
        Standard deviation (m/s) of a velocity impulse when ``impulse_scale`` is not given.
    reward_sigma : float
        Width of the bounded reward ``exp(-|phi~| / sigma)`` when ``reward_sigma`` is not given.
    phi_units : str
        Units of ``phi``, for tables and docs.
    phi_sf_meaning : str
        What the scale-free ``phi~`` is, for tables and docs.
    phi_sf_scale : float
        ``phi~ = phi / phi_sf_scale`` (in ``phi``'s units) unless ``observe`` writes its own.
    angles : tuple of int
        The state's coordinates that are angles: an observer takes their differences modulo 2 pi,
        and a run whose angle leaves the inline sine's range ends as non-finite.
    uncertain : tuple of str
        Names of the parameters the ``mismatch`` scenario perturbs (an adaptive controller estimates
        them), in [`controller_model`][vnhc_gym.tasks.base.Task.controller_model]'s parameter names.
    filtered_params : tuple of str
        Parameters of [`controller_model`][vnhc_gym.tasks.base.Task.controller_model] that a
        controller reads from the observation and that change along an episode (a current's local
        model): a Kalman filter estimates them with the state.
    draw_stages : int
        Number of stages of ``draw`` (a stage after the first sees the model's outputs at the state
        drawn so far).
    mismatch_stage : int
        The true parameters are drawn just before this stage of ``draw`` (0: before the task draws
        anything; ``draw_stages``: after it is done).

    Notes
    -----
    Instance attributes, set by the subclass's constructor:

    - ``config`` ([`EnvConfig`][vnhc_gym.envs.config.EnvConfig]): the settings every task shares.
    - ``options`` ([`TaskOptions`][vnhc_gym.envs.config.TaskOptions]): the task's own options.
    - ``model`` ([`ConstrainedSystem`][vnhc_gym.mechanics.ConstrainedSystem]): the compiled system
      with the constraint, the environment's dynamics.
    - ``nominal`` (ndarray): the nominal parameter vector of ``model`` (what a controller is told).
    - ``args`` (NamedTuple): the constants the hooks read.
    - ``obs_dim`` (int): the observation size.
    - ``impulse_mask`` (ndarray, shape ``(n,)``): weights of the velocity entries that impulses kick
      (0 = never).
    - ``limits`` (tuple of ``(str, int, float)``): ``(reason, index, bound)``: the episode ends with
      ``reason`` when ``|state[index]| > bound`` (checked in order, after the code ``observe``
      returns; default none).
    """

    name: ClassVar[str]
    Options: ClassVar[type[TaskOptions]] = TaskOptions
    reasons: ClassVar[Mapping[str, int]] = {}
    default_force_bound: ClassVar[float | tuple[float, ...]]
    force_units: ClassVar[str | tuple[str, ...]] = "N"
    default_impulse_scale: ClassVar[float]
    reward_sigma: ClassVar[float] = 0.1
    phi_units: ClassVar[str] = ""
    phi_sf_meaning: ClassVar[str] = ""
    phi_sf_scale: float = 1.0  # a class attribute, or set by the constructor from the options
    angles: ClassVar[tuple[int, ...]] = ()
    uncertain: ClassVar[tuple[str, ...]] = ()
    filtered_params: ClassVar[tuple[str, ...]] = ()
    draw_stages: ClassVar[int] = 1
    mismatch_stage: ClassVar[int] = 0

    config: EnvConfig
    options: TaskOptions
    model: ConstrainedSystem
    nominal: Array
    args: NamedTuple
    obs_dim: int
    impulse_mask: Array
    limits: tuple[tuple[str, int, float], ...] = ()

    def __init__(self, config: EnvConfig, options: TaskOptions) -> None:
        self.config = config
        self.options = options

    @property
    def act_dim(self) -> int:
        """Number of controls (= action entries = constraint components)."""
        return self.model.m

    @property
    def force_bound(self) -> Array:
        """Force of action 1, per control: ``force_bound`` (one number for every control) or the
        task's default, times ``force_bound_scale``."""
        c = self.config
        bound = c.force_bound if c.force_bound is not None else self.default_force_bound
        return np.broadcast_to(np.asarray(bound, dtype=np.float64), (self.act_dim,)) * c.force_bound_scale

    @property
    def units(self) -> tuple[str, ...]:
        """Units of each control."""
        u = self.force_units
        return (u,) * self.act_dim if isinstance(u, str) else tuple(u)

    @property
    def reason_codes(self) -> dict[str, int]:
        """Every termination reason's code: the declared ``reasons``, then the reasons that only
        ``limits`` name, numbered on."""
        codes = dict(self.reasons)
        for reason, _, _ in self.limits:
            if reason not in codes:
                codes[reason] = max(codes.values(), default=0) + 1
        return codes

    @property
    def all_reasons(self) -> tuple[str | None, ...]:
        """``termination_reason`` by status (None for "no termination"); code ``c`` is status ``1 + c``."""
        codes = self.reason_codes
        out: list[str | None] = [None, "non_finite_state"] + [None] * (max(codes.values(), default=0))
        for reason, code in codes.items():
            out[1 + code] = reason
        return tuple(out)

    @classmethod
    def check_definition(cls) -> None:
        """``ValueError`` if the class's declarations are inconsistent (codes, stages)."""
        codes = list(dict(cls.reasons).values())
        if any(not isinstance(c, int) or isinstance(c, bool) or c < 1 for c in codes) or len(set(codes)) != len(codes):
            raise ValueError(f"{cls.__name__}.reasons must map names to distinct integer codes >= 1, "
                             f"got {cls.reasons!r}")
        if "non_finite_state" in cls.reasons:
            raise ValueError(f"{cls.__name__}.reasons: 'non_finite_state' is common to every task")
        if not (isinstance(cls.draw_stages, int) and cls.draw_stages >= 1
                and isinstance(cls.mismatch_stage, int) and 0 <= cls.mismatch_stage <= cls.draw_stages):
            raise ValueError(f"{cls.__name__}: need draw_stages >= 1 and 0 <= mismatch_stage <= draw_stages, got "
                             f"{cls.draw_stages!r} and {cls.mismatch_stage!r}")

    def check_sizes(self) -> None:
        """``ValueError`` naming the task and the size if a size the task declares disagrees with what
        its constructor set or its hooks write.

        Why: the compiled kernels index fixed-size buffers without bounds checks, so a hook that
        writes past its row (an ``observe`` that writes 9 entries where ``obs_dim`` says 7) would
        corrupt memory instead of raising.  Each hook runs here once, on buffers padded with a marker,
        before any kernel does: a write past the declared size changes the padding, an entry the
        hook never writes keeps the marker.
        """
        import sys

        from vnhc_gym.rng import seed_states

        model = self.model
        where = f"task {self.name!r} ({type(self).__module__})"
        n_state, m, n_params = 2 * model.n, model.m, len(model.param_names)
        if not isinstance(self.obs_dim, (int, np.integer)) or isinstance(self.obs_dim, bool) or self.obs_dim < 1:
            raise ValueError(f"{where}: obs_dim must be a positive integer, got {self.obs_dim!r}")
        if np.shape(self.nominal) != (n_params,):
            raise ValueError(f"{where}: nominal has shape {np.shape(self.nominal)}, but the system has {n_params} "
                             f"parameters {model.param_names}")
        if np.shape(self.impulse_mask) != (model.n,):
            raise ValueError(f"{where}: impulse_mask has shape {np.shape(self.impulse_mask)}, but the system has "
                             f"{model.n} velocity entries")
        for label, indices in (("limits", [i for _, i, _ in self.limits]), ("angles", list(self.angles))):
            bad = [i for i in indices if not (isinstance(i, (int, np.integer)) and 0 <= i < n_state)]
            if bad:
                raise ValueError(f"{where}: {label} index {bad} outside the state's {n_state} entries")
        hooks = sys.modules[type(self).__module__]
        # The hooks' Python functions (numba keeps them as ``py_func``) on buffers of exactly the
        # declared sizes: numpy raises IndexError where the compiled code would write out of bounds.
        draw = getattr(hooks.draw, "py_func", hooks.draw)
        observe = getattr(hooks.observe, "py_func", hooks.observe)
        mark = -7.25e300  # a value no hook writes: an observation entry still holding it was never written
        state = np.zeros(n_state)
        params = np.array(self.nominal, dtype=np.float64)
        n_aux = len(model.output_names)
        aux = np.zeros(max(n_aux, 1))
        rng = seed_states([0])
        try:
            for stage in range(self.draw_stages):
                if stage > 0 and n_aux:
                    aux[:n_aux] = model.outputs(state, params)
                draw(rng, 0, stage, state, params, aux, self.args)
        except IndexError as exc:
            raise ValueError(f"{where}: draw indexes past a buffer (state has {n_state} entries, params "
                             f"{n_params}, aux {aux.size}): {exc}") from None
        obs = np.full(self.obs_dim, mark)
        phi_sf = np.zeros(m)
        if n_aux:
            aux[:n_aux] = model.outputs(state, params)
        try:
            observe(state, model.phi(state, params), aux, self.args, obs, phi_sf)
        except IndexError as exc:
            raise ValueError(f"{where}: observe writes past the observation's obs_dim = {self.obs_dim} entries "
                             f"(or past phi_sf's {m}, one per constraint component): {exc}") from None
        if (obs == mark).any():
            raise ValueError(f"{where}: observe leaves observation entries {np.flatnonzero(obs == mark).tolist()} "
                             f"unwritten, but obs_dim is {self.obs_dim}")

    # ------------------------------------------------------------------ the pure-function environment
    def functional(self, feedback: str = "open", gains: Any = 1.0, max_steps: int = 400) -> Any:
        """This configured task as a [`FunctionalEnv`][vnhc_gym.envs.functional.FunctionalEnv] (gymnax's
        interface) and its parameters: the task module's pure ``initial``, ``observation`` and optional
        ``terminations``, ``task_params`` and ``scale_free``, on the task's printed system
        ([`jax_system`][vnhc_gym.tasks.base.Task.jax_system]); a function with a keyword parameter
        ``system`` is given it (a task whose system depends on its options, the USV's current).

        Parameters
        ----------
        feedback : {"open", "continuous", "sampled"}
            The stabilising law inside the integrator (see `FunctionalEnv`).
        gains : float or array_like
            The in-loop law's gains.
        max_steps : int
            The time limit of `FunctionalEnv.step`'s automatic reset (the registry's 400).
        """
        import inspect
        import sys
        from functools import partial

        import jax.numpy as jnp

        from vnhc_gym.envs.functional import EnvParams, FunctionalEnv, TaskFunctions

        module = sys.modules[type(self).__module__]
        where = f"task {self.name!r} ({type(self).__module__})"
        missing = [f for f in ("initial", "observation") if not callable(getattr(module, f, None))]
        if missing:
            raise ValueError(f"{where}: the module defines no pure {' or '.join(missing)} function")
        system = self.jax_system()
        c = self.config
        names = self.model.param_names
        n_gains = 2 * system.M if system.HOLONOMIC else system.M
        k = np.broadcast_to(np.asarray(gains, dtype=np.float64), (n_gains,))
        def bound(name: str) -> Any:
            """The module's function ``name`` (or None), given the printed system if it asks for it."""
            fn = getattr(module, name, None)
            if fn is not None and "system" in inspect.signature(fn).parameters:
                fn = partial(fn, system=system)
            return fn

        fns = TaskFunctions(
            name=self.name, system=system, initial=bound("initial"), observation=bound("observation"),
            terminations=bound("terminations"), task_params=bound("task_params"), scale_free=bound("scale_free"),
            reasons=tuple(str(r) for r in self.all_reasons[1:]),
            limits=tuple((r, int(i)) for r, i, _ in self.limits),
            impulse_mask=tuple(float(w) for w in self.impulse_mask),
            uncertain=tuple(n in self.uncertain for n in names), obs_dim=int(self.obs_dim))
        f = jnp.asarray
        params = EnvParams(
            nominal=f(self.nominal), force_bound=f(self.force_bound), dt=f(c.dt), param_mismatch=f(c.param_mismatch),
            obs_noise=f(c.obs_noise), obs_clip=f(c.obs_clip), impulse_prob=f(c.impulse_prob),
            impulse_scale=f(self.default_impulse_scale if c.impulse_scale is None else c.impulse_scale),
            reward_sigma=f(self.reward_sigma if c.reward_sigma is None else c.reward_sigma),
            phi_scale=f(c.phi_scale), phi_sf_scale=f(float(self.phi_sf_scale)), action_cost=f(c.action_cost),
            reward_clip=f(c.reward_clip), gains=f(k), limit_bounds=f(np.array([b for _, _, b in self.limits])),
            args=self.args, max_steps_in_episode=int(max_steps))
        env = FunctionalEnv(task=fns, default_params=params, substeps=int(c.substeps), reward=c.reward,
                            feedback=feedback)
        return env, params

    def jax_system(self) -> Any:
        """The printed JAX module of the environment's system (`vnhc_gym.systems.printed`)."""
        from vnhc_gym.systems.printed import printed_for

        system = printed_for(self.model)
        if system is None:
            raise ValueError(f"task {self.name!r}: no printed system for {getattr(self.model, 'recipe', None)!r}")
        return system

    # ------------------------------------------------------------------ what a controller reads
    def controller_model(self) -> ConstrainedSystem:
        """The model a model-based controller uses (default: the environment's own system)."""
        return self.model

    def controller_inputs(self, obs: Array) -> tuple[Array, Array]:
        """States and parameters of [`controller_model`][vnhc_gym.tasks.base.Task.controller_model]
        rebuilt from observations ``(B, d)``.

        The parameters are the nominal ones (a controller is never told the true ones); entries
        the law does not depend on (positions of free-falling particles, say) may be zero.
        """
        raise NotImplementedError

    def observation_of(self, states: Array, params: Array) -> Array:
        """Noise-free observations ``(B, obs_dim)`` of controller states and parameters: the task's
        own ``observe`` at each state, with ``phi`` and the extra outputs of
        [`controller_model`][vnhc_gym.tasks.base.Task.controller_model] (a filter's measurement model).

        It inverts [`controller_inputs`][vnhc_gym.tasks.base.Task.controller_inputs] where that reads
        the state back from the observation; the observation's clipping is left out.
        """
        import sys

        hooks = sys.modules[type(self).__module__]
        observe = getattr(hooks.observe, "py_func", hooks.observe)  # the hook's own Python function
        model = self.controller_model()
        s = np.asarray(states, dtype=np.float64)
        p = np.asarray(params, dtype=np.float64)
        phi = model.phi(s, p)
        aux = model.outputs(s, p) if model.output_names else np.zeros((s.shape[0], 1))
        out = np.empty((s.shape[0], self.obs_dim))
        sf = np.empty(self.act_dim)
        for i in range(s.shape[0]):
            observe(s[i], phi[i], aux[i], self.args, out[i], sf)
        return out

    def recenter(self, states: Array, params: Array) -> tuple[Array, Array]:
        """Controller states and parameters predicted one step ahead, expressed in the frame of the
        next [`controller_inputs`][vnhc_gym.tasks.base.Task.controller_inputs] (identity unless that
        frame moves with the system)."""
        return states, params

    def scene(self, state: Array, phi: Array, params: Array) -> Any:
        """What a frame shows of one episode (a [`Scene`][vnhc_gym.envs.rendering.Scene]: bodies,
        links, every ``phi`` component), from its state, ``phi`` and true parameters.  A task that
        does not define it has no render modes."""
        raise NotImplementedError

    def describe(self) -> dict[str, Any]:
        """A JSON-friendly summary of the configured task (for result files)."""
        return {"task": self.name, "config": {k: getattr(self.config, k) for k in self.config.__dataclass_fields__},
                "options": asdict(self.options), "force_bound": self.force_bound.tolist(), "units": list(self.units),
                "obs_dim": self.obs_dim, "act_dim": self.act_dim}
