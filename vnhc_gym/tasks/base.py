"""What a task is: the one definition that the environments, baselines, training and evaluation read.

A task module (``vnhc_gym/tasks/sled.py`` is one) holds, in this order:

1. its functions' constants (a ``NamedTuple`` called ``Args``) and its pure ``jax.numpy`` functions of
   one episode: ``initial`` (the start state), ``observation``, and where the task has them
   ``terminations`` (named predicates), ``task_params`` (random parameters of the task's own) and
   ``scale_free`` (its own scale-free ``phi``);
2. its options (a [`TaskOptions`][vnhc_gym.envs.config.TaskOptions] dataclass) and its
   [`Task`][vnhc_gym.tasks.base.Task] subclass: the mechanical system and constraint, the functions'
   constants, the observation size, the force bounds, the termination reasons by name, and how a
   controller reads the state back from an observation;
3. the environment class with its card (a subclass of [`ConstraintEnv`][vnhc_gym.envs.env.ConstraintEnv]);
   the registry makes its native vector version.

One line in `vnhc_gym.tasks` registers it.  Everything else is common to every task and done once,
by [`FunctionalEnv`][vnhc_gym.envs.functional.FunctionalEnv]: the nominal parameters and the
mismatch draw, impulses, RK4, the non-finite check, the status, observation noise and clipping, the
scale-free ``phi`` (``phi / phi_sf_scale`` unless the task writes its own) and the reward.  The
functions' signatures are in that module's docstring.
"""

from __future__ import annotations

import inspect
import sys
from functools import partial
from typing import Any, ClassVar, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from numpy.typing import NDArray

from vnhc_gym.envs.config import EnvConfig, TaskOptions
from vnhc_gym.envs.functional import EnvParams, FunctionalEnv, TaskFunctions
from vnhc_gym.mechanics import ConstrainedSystem

__all__ = ["Task"]

Array = NDArray[np.float64]

#: `Task.observation_model` and its compiled, batched form (`Task.observation_of`), by task class and
#: printed system.
_OBSERVATION_MODELS: dict[tuple[type, Any], Any] = {}
_OBSERVATIONS: dict[tuple[type, Any], Any] = {}
#: The compiled, batched pure functions of a task module (`Task.controller_inputs`, `_batched`).
_CHARTS: dict[Any, Any] = {}


def _batched(fn: Any, states: Array, params: Array, args: Any) -> Any:
    """A task module's pure ``fn(s, p, args)`` on every row of ``(B, .)`` states and parameters, in
    float64, as writable numpy arrays (a tuple of them where ``fn`` returns a tuple)."""
    batched = _CHARTS.get(fn)
    if batched is None:
        batched = _CHARTS[fn] = jax.jit(jax.vmap(fn, in_axes=(0, 0, None)))
    with jax.enable_x64(True):
        out = batched(np.asarray(states, dtype=np.float64), np.asarray(params, dtype=np.float64), args)
    return jax.tree.map(lambda a: np.array(a, dtype=np.float64), out)

def bound_fn(module: Any, name: str, system: Any) -> Any:
    """A task module's function ``name`` (or None), given the printed system if it asks for it."""
    fn = getattr(module, name, None)
    if fn is not None and "system" in inspect.signature(fn).parameters:
        fn = partial(fn, system=system)
    return fn


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
    reasons : tuple of str
        The names of the task's ``terminations``, in the order they are checked;
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
    phi_sf_scale : float
        ``phi~ = phi / phi_sf_scale`` (in ``phi``'s units) unless the module defines ``scale_free``.
    angles : tuple of int
        The state's coordinates that are angles: an observer or a filter takes their differences
        modulo 2 pi.
    uncertain : tuple of str
        Names of the parameters the ``mismatch`` scenario perturbs (an adaptive controller estimates
        them), in [`controller_model`][vnhc_gym.tasks.base.Task.controller_model]'s parameter names.
    filtered_params : tuple of str
        Parameters of [`controller_model`][vnhc_gym.tasks.base.Task.controller_model] that a
        controller reads from the observation and that change along an episode (a current's local
        model): a Kalman filter estimates them with the state.
    unmeasured : tuple of int
        Observation entries that a filter's measurement model leaves out (NaN in
        [`observation_of`][vnhc_gym.tasks.base.Task.observation_of]): the boat's position, which
        the frame centred on the boat does not hold.
    scenario_magnitudes : dict of str to dict
        The task's own values of a scenario's fields where ``SCENARIOS``' do not suit it (a shorter
        delay for a pole that falls in a fraction of a second), by scenario; its card states them.
    unmodelled_ranges : dict of str to (float, float)
        The coefficients of the module's ``unmodelled(s, p, c, args)`` (the accelerations of forces
        the nominal model lacks, for the ``unmodelled`` scenario), by name, in order, with the range
        each is drawn from per episode.

    Notes
    -----
    Instance attributes, set by the subclass's constructor:

    - ``config`` ([`EnvConfig`][vnhc_gym.envs.config.EnvConfig]): the settings every task shares.
    - ``options`` ([`TaskOptions`][vnhc_gym.envs.config.TaskOptions]): the task's own options.
    - ``model`` ([`ConstrainedSystem`][vnhc_gym.mechanics.ConstrainedSystem]): the compiled system
      with the constraint, the environment's dynamics.
    - ``nominal`` (ndarray): the nominal parameter vector of ``model`` (what a controller is told).
    - ``args`` (NamedTuple): the constants the task's functions read.
    - ``obs_dim`` (int): the observation size.
    - ``impulse_mask`` (ndarray, shape ``(n,)``): weights of the velocity entries that impulses kick
      (0 = never).
    - ``limits`` (tuple of ``(str, int, float)``): ``(reason, index, bound)``: the episode ends with
      ``reason`` when ``|state[index]| > bound`` (checked in order, after ``terminations``;
      default none).
    """

    name: ClassVar[str]
    Options: ClassVar[type[TaskOptions]] = TaskOptions
    reasons: ClassVar[tuple[str, ...]] = ()
    default_force_bound: ClassVar[float | tuple[float, ...]]
    force_units: ClassVar[str | tuple[str, ...]] = "N"
    default_impulse_scale: ClassVar[float]
    reward_sigma: ClassVar[float] = 0.1
    phi_units: ClassVar[str] = ""
    phi_sf_scale: float = 1.0  # a class attribute, or set by the constructor from the options
    angles: ClassVar[tuple[int, ...]] = ()
    uncertain: ClassVar[tuple[str, ...]] = ()
    filtered_params: ClassVar[tuple[str, ...]] = ()
    unmeasured: ClassVar[tuple[int, ...]] = ()
    unmodelled_ranges: ClassVar[dict[str, tuple[float, float]]] = {}
    scenario_magnitudes: ClassVar[dict[str, dict[str, Any]]] = {}

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
    def all_reasons(self) -> tuple[str | None, ...]:
        """``termination_reason`` by status: None (no termination), ``"non_finite_state"``, the
        declared ``reasons``, then the reasons that only ``limits`` name."""
        names: list[str | None] = [None, "non_finite_state", *self.reasons]
        names += list(dict.fromkeys(r for r, _, _ in self.limits if r not in names))
        return tuple(names)

    @classmethod
    def check_definition(cls) -> None:
        """``ValueError`` if the class's declared reasons are not distinct names."""
        reasons = cls.reasons
        if (not isinstance(reasons, tuple) or not all(isinstance(r, str) and r for r in reasons)
                or len(set(reasons)) != len(reasons)):
            raise ValueError(f"{cls.__name__}.reasons must be a tuple of distinct names, got {reasons!r}")
        if "non_finite_state" in reasons:
            raise ValueError(f"{cls.__name__}.reasons: 'non_finite_state' is common to every task")

    def check_sizes(self) -> None:
        """``ValueError`` naming the task and the function if a size the task declares disagrees with
        what its constructor set or its functions return (traced with ``jax.eval_shape``: nothing runs)."""
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
        env, params = self.functional()
        fns = env.task
        key = jax.ShapeDtypeStruct((2,), np.uint32)
        s = jax.ShapeDtypeStruct((n_state,), np.float32)
        p = jax.ShapeDtypeStruct((n_params,), np.float32)
        phi = jax.ShapeDtypeStruct((m,), np.float32)
        args = params.args
        checks: list[tuple[str, Any, tuple[Any, ...], tuple[int, ...], str]] = [
                  ("initial", fns.initial, (key, p, args), (n_state,), "the state's 2n entries"),
                  ("observation", fns.observation, (s, phi, p, args), (self.obs_dim,), "obs_dim")]
        if fns.task_params is not None:
            checks.append(("task_params", fns.task_params, (key, p, args), (n_params,), "the system's parameters"))
        if fns.scale_free is not None:
            checks.append(("scale_free", fns.scale_free, (s, phi, args), (m,), "one per control"))
        if fns.unmodelled is not None:
            c = jax.ShapeDtypeStruct((len(fns.unmodelled_ranges),), np.float32)
            checks.append(("unmodelled", fns.unmodelled, (s, p, c, args), (model.n,), "the velocity's n entries"))
        chart = getattr(sys.modules[type(self).__module__], "controller_inputs", None)
        if callable(chart):
            ctrl = self.controller_model()
            o = jax.ShapeDtypeStruct((int(self.obs_dim),), np.float32)
            checks += [("controller_inputs (its state)", lambda *a: chart(*a)[0], (o, p, args), (2 * ctrl.n,),
                        "the controller model's 2n entries"),
                       ("controller_inputs (its parameters)", lambda *a: chart(*a)[1], (o, p, args),
                        (len(ctrl.param_names),), "the controller model's parameters")]
            cs = jax.ShapeDtypeStruct((2 * ctrl.n,), np.float32)
            cp = jax.ShapeDtypeStruct((len(ctrl.param_names),), np.float32)
            move, drift = self.frame_functions()
            if move is not None:
                checks += [("recenter (its state)", lambda *a: move(*a)[0], (cs, cp, args), (2 * ctrl.n,),
                            "the controller model's 2n entries"),
                           ("recenter (its parameters)", lambda *a: move(*a)[1], (cs, cp, args),
                            (len(ctrl.param_names),), "the controller model's parameters")]
            if drift is not None:
                checks.append(("parameter_drift", drift, (cs, cp, args), (2 * ctrl.n, len(self.filtered_params)),
                               "the controller state's 2n entries by the filtered_params"))
        bad = [i for i in self.unmeasured if not (isinstance(i, (int, np.integer)) and 0 <= i < self.obs_dim)]
        if bad:
            raise ValueError(f"{where}: unmeasured index {bad} outside the observation's {self.obs_dim} entries")
        for name, fn, inputs, shape, what in checks:
            got = jax.eval_shape(fn, *inputs).shape
            if tuple(got) != shape:
                raise ValueError(f"{where}: {name} returns shape {tuple(got)}, but {what} makes it {shape}")
        if fns.terminations is not None:
            names = tuple(jax.eval_shape(fns.terminations, s, phi, args))
            if names != self.reasons:
                raise ValueError(f"{where}: terminations returns the reasons {names}, but the task declares "
                                 f"reasons = {self.reasons}")
        elif self.reasons:
            raise ValueError(f"{where}: reasons {self.reasons} are declared, but the module defines no terminations")

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
        module = sys.modules[type(self).__module__]
        where = f"task {self.name!r} ({type(self).__module__})"
        missing = [f for f in ("initial", "observation") if not callable(getattr(module, f, None))]
        if missing:
            raise ValueError(f"{where}: the module defines no pure {' or '.join(missing)} function")
        system = self.jax_system()
        c = self.config
        names = self.model.param_names
        ranges = tuple((float(lo), float(hi)) for lo, hi in self.unmodelled_ranges.values())
        unmodelled = bound_fn(module, "unmodelled", system)
        if (unmodelled is None) != (not ranges):
            raise ValueError(f"{where}: unmodelled_ranges and the module's unmodelled function go together, got "
                             f"{len(ranges)} coefficient(s) and {'a' if unmodelled else 'no'} function")
        if c.unmodelled > 0 and unmodelled is None:
            raise ValueError(f"{where}: unmodelled={c.unmodelled:g}, but the task declares no unmodelled forces "
                             f"(define unmodelled(s, p, c, args) and unmodelled_ranges)")
        n_gains = 2 * system.M if system.HOLONOMIC else system.M
        k = np.broadcast_to(np.asarray(gains, dtype=np.float64), (n_gains,))
        def bound(name: str) -> Any:
            return bound_fn(module, name, system)

        ctrl = self.controller_model()
        fns = TaskFunctions(
            name=self.name, system=system, initial=bound("initial"), observation=bound("observation"),
            terminations=bound("terminations"), task_params=bound("task_params"), scale_free=bound("scale_free"),
            controller_inputs=bound("controller_inputs"),
            controller_system=system if ctrl is self.model else ctrl.functions,
            controller_singular_tol=ctrl.singular_tol,
            reasons=tuple(str(r) for r in self.all_reasons[1:]),
            limits=tuple((r, int(i)) for r, i, _ in self.limits),
            impulse_mask=tuple(float(w) for w in self.impulse_mask),
            uncertain=tuple(n in self.uncertain for n in names), obs_dim=int(self.obs_dim),
            unmodelled=unmodelled, unmodelled_ranges=ranges)

        def f(x: Any) -> Any:
            return np.asarray(x, dtype=np.float64)  # float64: JAX casts it to its own precision at a call

        params = EnvParams(
            nominal=f(self.nominal), force_bound=f(self.force_bound), dt=f(c.dt), param_mismatch=f(c.param_mismatch),
            obs_noise=f(c.obs_noise), obs_clip=f(c.obs_clip), impulse_prob=f(c.impulse_prob),
            impulse_scale=f(self.default_impulse_scale if c.impulse_scale is None else c.impulse_scale),
            reward_sigma=f(self.reward_sigma if c.reward_sigma is None else c.reward_sigma),
            phi_scale=f(c.phi_scale), phi_sf_scale=f(float(self.phi_sf_scale)), action_cost=f(c.action_cost),
            reward_clip=f(c.reward_clip), gains=f(k), limit_bounds=f(np.array([b for _, _, b in self.limits])),
            args=self.args, delay_range=f([c.delay_min, c.delay_max]), lag_range=f([c.lag_min, c.lag_max]),
            unmodelled_scale=f(c.unmodelled), redraw=f(float(c.redraw)), max_steps_in_episode=int(max_steps))
        env = FunctionalEnv(task=fns, default_params=params, substeps=int(c.substeps), reward=c.reward,
                            feedback=feedback, delay_slots=int(c.delay_max), structural=c.structural)
        return env, params

    def jax_system(self) -> Any:
        """The environment's system as pure JAX functions: its printed module
        (`vnhc_gym.systems.printed`), or for a system the package does not ship (a user's), its law
        lambdified on first use ([`LambdifiedSystem`][vnhc_gym.mechanics.lambdified.LambdifiedSystem])."""
        return self.model.functions

    # ------------------------------------------------------------------ what a controller reads
    def controller_model(self) -> ConstrainedSystem:
        """The model a model-based controller uses (default: the environment's own system)."""
        return self.model

    def controller_functions(self) -> Any:
        """[`controller_model`][vnhc_gym.tasks.base.Task.controller_model] as printed JAX functions
        (the environment's own [`jax_system`][vnhc_gym.tasks.base.Task.jax_system] unless the
        controllers run a model of their own)."""
        model = self.controller_model()
        return self.jax_system() if model is self.model else model.functions

    def controller_inputs(self, obs: Array) -> tuple[Array, Array]:
        """States and parameters of [`controller_model`][vnhc_gym.tasks.base.Task.controller_model]
        read back from observations ``(B, d)``: the task module's pure ``controller_inputs(obs, p,
        args) -> (s, p_controller)`` for each row, with the nominal parameters ``p``, in float64.

        The parameters are the nominal ones (a controller is never told the true ones); entries
        the law does not depend on (positions of free-falling particles, say) may be zero.

        Raises
        ------
        NotImplementedError
            If the task's module defines no ``controller_inputs``.
        """
        module = sys.modules[type(self).__module__]
        one = getattr(module, "controller_inputs", None)
        if not callable(one):
            raise NotImplementedError(f"task {self.name!r}: its module {module.__name__} defines no pure "
                                      f"controller_inputs(obs, p, args), so no controller can read its observations")
        fn = _CHARTS.get(one)
        if fn is None:
            fn = _CHARTS[one] = jax.jit(jax.vmap(one, in_axes=(0, None, None)))
        with jax.enable_x64(True):
            s, p = fn(np.asarray(obs, dtype=np.float64), np.asarray(self.nominal, dtype=np.float64), self.args)
        return np.array(s, dtype=np.float64), np.array(p, dtype=np.float64)  # writable copies

    def informed_params(self, states: Array, params_true: Array) -> Array:
        """Parameters of [`controller_model`][vnhc_gym.tasks.base.Task.controller_model] for a controller
        told the episode's true parameters ``(B, n_params)`` (the environment's; ``states`` are its true
        states, for a controller model whose parameters depend on where the system is): the reference
        `vnhc_gym.baselines.InformedKalmanController`.  Default: the true parameters themselves, which
        holds when the controller model is the environment's own system.

        Raises
        ------
        NotImplementedError
            For a task whose controller model is not its own system and that does not define it.
        """
        if type(self).controller_model is not Task.controller_model:
            raise NotImplementedError(f"task {self.name!r}: its controllers run a model of their own "
                                      f"(controller_model), so it must define informed_params")
        return np.array(params_true, dtype=np.float64)

    def observation_model(self) -> Any:
        """The noise-free observation of one controller state as a pure JAX function ``(s, p, chart,
        args) -> obs``: the task's ``observation`` on [`controller_model`][vnhc_gym.tasks.base.Task.controller_model]'s
        printed system, with ``phi`` from the parameters ``p`` and the rest of the observation from
        ``chart`` (an environment observes with the nominal parameters it tells a controller, which
        differ from the true ones that drive ``phi`` under mismatch), and the ``unmeasured`` entries
        NaN (a filter's measurement model)."""
        system = self.controller_functions()
        key = (type(self), system)
        if key in _OBSERVATION_MODELS:  # one function a task and system: equal filters share compiled code
            return _OBSERVATION_MODELS[key]
        observation = sys.modules[type(self).__module__].observation
        if "system" in inspect.signature(observation).parameters:
            observation = partial(observation, system=system)
        # A mask, not an index array: an empty numpy index is int64, which a program traced without
        # x64 (the compiled trainers) refuses to scatter with.
        unmeasured = np.zeros(int(self.obs_dim), dtype=bool)
        unmeasured[list(self.unmeasured)] = True

        def one(s: Any, p: Any, chart: Any, args: Any) -> Any:
            out = observation(s, system.phi(s, p), chart, args)
            return jnp.where(unmeasured, jnp.asarray(np.nan, out.dtype), out)

        _OBSERVATION_MODELS[key] = one
        return one

    def observation_of(self, states: Array, params: Array, chart: Array | None = None) -> Array:
        """Noise-free observations ``(B, obs_dim)`` of controller states and parameters: the task's
        [`observation_model`][vnhc_gym.tasks.base.Task.observation_model] at each state (``chart``
        defaults to ``params``).

        It inverts [`controller_inputs`][vnhc_gym.tasks.base.Task.controller_inputs] where that reads
        the state back from the observation; the observation's clipping is left out.
        """
        key = (type(self), self.controller_functions())
        fn = _OBSERVATIONS.get(key)
        if fn is None:
            fn = _OBSERVATIONS[key] = jax.jit(jax.vmap(self.observation_model(), in_axes=(0, 0, 0, None)))
        with jax.enable_x64(True):
            p = np.asarray(params, dtype=np.float64)
            out = fn(np.asarray(states, dtype=np.float64), p, p if chart is None else np.asarray(chart, np.float64),
                     self.args)
        return np.array(out, dtype=np.float64)  # a writable copy

    def frame_functions(self) -> tuple[Any, Any]:
        """The task module's pure ``recenter(s, p, args) -> (s, p)`` and ``parameter_drift(s, p, args)
        -> (2n, len(filtered_params))`` (each None where the module defines none): what a Kalman
        filter needs of a task whose controller frame moves with the system or whose filtered
        parameters carry the state.  See [`recenter`][vnhc_gym.tasks.base.Task.recenter] and
        [`parameter_drift`][vnhc_gym.tasks.base.Task.parameter_drift]."""
        module = sys.modules[type(self).__module__]
        return getattr(module, "recenter", None), getattr(module, "parameter_drift", None)

    def parameter_drift(self, states: Array, params: Array) -> Array:
        """How the state moves with an unpredicted step of the
        [`filtered_params`][vnhc_gym.tasks.base.Task] (a Kalman filter's random walk of them):
        ``(B, 2 n, k)``, the state's change per unit change of each of the ``k`` parameters, at
        controller states and parameters ``(B, 2 n)``, ``(B, n_params)``: the module's pure
        ``parameter_drift`` at each row; zero where it defines none (no filtered parameter is also
        carried by the state)."""
        fn = self.frame_functions()[1]
        if fn is None:
            return np.zeros((states.shape[0], states.shape[1], len(self.filtered_params)))
        return _batched(fn, states, params, self.args)

    def recenter(self, states: Array, params: Array) -> tuple[Array, Array]:
        """Controller states and parameters predicted one step ahead, expressed in the frame of the
        next [`controller_inputs`][vnhc_gym.tasks.base.Task.controller_inputs]: the module's pure
        ``recenter`` at each row (identity where it defines none: the frame does not move)."""
        fn = self.frame_functions()[0]
        if fn is None:
            return states, params
        s, p = _batched(fn, states, params, self.args)
        return s, p

    def scene(self, state: Array, phi: Array, params: Array) -> Any:
        """What a frame shows of one episode (a [`Scene`][vnhc_gym.envs.rendering.Scene]: bodies,
        links, every ``phi`` component), from its state, ``phi`` and true parameters.  A task that
        does not define it has no render modes."""
        raise NotImplementedError

    @classmethod
    def draws(cls) -> bool:
        """Whether the task defines its own `scene` (an environment of a task that does not has no
        render modes)."""
        return cls.scene is not Task.scene
