"""The native vector environment of any task: ``num_envs`` episodes in one batch, one kernel call a step.

``gym.make_vec(id, num_envs=N, vectorization_mode="vector_entry_point", **kwargs)`` builds the
task's subclass of [`ConstraintVectorEnv`][vnhc_gym.envs.ConstraintVectorEnv].  It reproduces
``gymnasium.vector.SyncVectorEnv`` over ``N`` single environments made with
``gym.make(id, **kwargs)`` exactly: observations, rewards, terminations, truncations and infos
(Gymnasium's dict-of-arrays convention with ``_key`` masks), in ``AutoresetMode.NEXT_STEP``
(default), ``SAME_STEP`` (``final_obs`` / ``final_info``) and ``DISABLED`` (reset finished sub-envs
yourself with ``reset(options={"reset_mask": mask})``).  ``reset(seed=s)`` seeds sub-env ``i`` with
``s + i`` as ``SyncVectorEnv`` does.
"""

from __future__ import annotations

import sys
from typing import Any, ClassVar

import numpy as np
from gymnasium.error import Error, ResetNeeded
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space
from numpy.typing import NDArray

from vnhc_gym.envs.config import check_integer
from vnhc_gym.envs.env import ConstraintEnv, check_action_array
from vnhc_gym.envs.runtime import Batch

__all__ = ["ConstraintVectorEnv", "MAX_EPISODE_STEPS", "vector_env_class"]

#: Episode length of the registered environments (400 steps of 0.05 s = 20 s).
MAX_EPISODE_STEPS = 400


def _check_seed(seed: Any) -> int:
    """The single env's seed rule (``gymnasium.utils.seeding.np_random``): an int >= 0."""
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer):
        raise Error(f"Seed must be a python integer, actual type: {type(seed)}")
    if seed < 0:
        raise Error(f"Seed must be greater or equal to zero, actual value: {seed}")
    return int(seed)


class ConstraintVectorEnv(VectorEnv):
    """``num_envs`` episodes of one task in one batch (see the module docstring).

    Parameters
    ----------
    num_envs : int
        Number of sub-environments.
    max_episode_steps : int or None
        Truncation after this many steps of a sub-environment's episode, like ``gym.make``'s
        ``TimeLimit`` (default 400; None: never truncate).
    autoreset_mode : AutoresetMode or str
        ``NEXT_STEP`` (default), ``SAME_STEP`` or ``DISABLED``, as in ``SyncVectorEnv``.
    **kwargs
        Every keyword argument of the single environment (``scenario``, ``render_mode``, ...),
        checked by the single environment's own constructor.

    Attributes
    ----------
    batch : Batch
        The batch of episodes (``batch.n == num_envs``); ``batch.set_feedback(...)`` acts on all rows.
    task : Task
        The configured task, shared by every sub-environment.
    """

    env_class: ClassVar[type[ConstraintEnv]]
    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["human", "rgb_array"], "render_fps": 20,  # type: ignore[misc]
                                          "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(self, num_envs: int = 1, *, max_episode_steps: int | None = MAX_EPISODE_STEPS,
                 autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP, **kwargs: Any) -> None:
        n = check_integer("num_envs", num_envs, low=1, high=10_000_000)
        if max_episode_steps is not None:
            max_episode_steps = check_integer("max_episode_steps", max_episode_steps, low=1)
        try:
            mode = autoreset_mode if isinstance(autoreset_mode, AutoresetMode) else AutoresetMode(autoreset_mode)
        except ValueError:
            raise ValueError(f"autoreset_mode must be one of {[m.value for m in AutoresetMode]}, "
                             f"got {autoreset_mode!r}") from None
        # The single env's constructor checks every argument and configures the task (same errors as
        # gym.make); it also draws sub-environment 0 when rendering.
        self._proto = self.env_class(**kwargs)
        self.task = self._proto.task
        self.batch = Batch(self.task, n)
        self._proto.batch = self.batch
        self.num_envs = n
        self.max_episode_steps = max_episode_steps
        self.autoreset_mode = mode
        self.metadata = {**type(self).metadata, **self._proto.metadata, "autoreset_mode": mode}  # type: ignore[misc]
        self.render_mode = self._proto.render_mode
        self.config = self.task.config
        self.scenario = self._proto.scenario
        self.dt = self._proto.dt
        self.single_observation_space = self._proto.observation_space
        self.single_action_space = self._proto.action_space
        self.observation_space = batch_space(self.single_observation_space, n)
        self.action_space = batch_space(self.single_action_space, n)
        self._all = np.arange(n, dtype=np.intp)
        self._ready = np.zeros(n, dtype=np.bool_)  # sub-envs reset at least once
        self._seeds: list[int | None] = [None] * n
        self._pending = np.zeros(n, dtype=np.bool_)  # sub-envs whose episode ended at the last step

    # ------------------------------------------------------------------ Gymnasium API
    def reset(self, *, seed: int | list[int | None] | None = None, options: dict[str, Any] | None = None
              ) -> tuple[NDArray[np.float32], dict[str, Any]]:
        """Reset all sub-environments (or those in ``options["reset_mask"]``).

        ``seed``: None (keep each sub-env's random stream; entropy on first use), an int ``s``
        (sub-env ``i`` gets ``s + i``) or a list of ``num_envs`` ints / None.
        """
        n = self.num_envs
        if seed is None:
            seeds: list[int | None] = [None] * n
        elif isinstance(seed, int | np.integer) and not isinstance(seed, bool):
            s0 = _check_seed(seed)
            seeds = [s0 + i for i in range(n)]
        else:
            seeds = list(seed)  # type: ignore[arg-type]
            if len(seeds) != n:
                raise ValueError(f"If seeds are passed as a list the length must match num_envs={n} "
                                 f"but got length={len(seeds)}.")
            seeds = [None if s is None else _check_seed(s) for s in seeds]
        mask = None
        if options is not None and "reset_mask" in options:
            mask = options["reset_mask"]
            if not isinstance(mask, np.ndarray):
                raise TypeError(f"`options['reset_mask']` must be a numpy array, got {type(mask)}")
            if mask.shape != (n,):
                raise ValueError(f"`options['reset_mask']` must have shape `({n},)`, got {mask.shape}")
            if mask.dtype != np.bool_:
                raise TypeError(f"`options['reset_mask']` must have `dtype=np.bool_`, got {mask.dtype}")
            if not np.any(mask):
                raise ValueError(f"`options['reset_mask']` must contain a boolean array with at least one True "
                                 f"value, got reset_mask={mask}")
        rows = self._all if mask is None else np.flatnonzero(mask)
        row_seeds = [seeds[i] for i in rows.tolist()]
        for i, s in zip(rows.tolist(), row_seeds, strict=True):
            if s is not None or not self.batch.seeded[i]:
                self._seeds[i] = s
        self.batch.seed(rows, row_seeds)
        self.batch.reset(rows)
        self._pending[rows] = False
        self._ready[rows] = True
        infos = self.batch.batch_info(None if mask is None else mask.copy())
        self._add_params(infos, rows)
        if self.render_mode == "human":
            self.render()
        return self.batch.buf.obs32.copy(), infos

    def step(self, actions: Any) -> tuple[NDArray[np.float32], NDArray[np.float64], NDArray[np.bool_],
                                          NDArray[np.bool_], dict[str, Any]]:
        """Step every sub-environment; actions ``(num_envs, act_dim)`` in ``[-1, 1]`` (clipped).

        Raises ``ValueError`` (and changes nothing) for a wrong shape or a non-finite row.
        """
        if not self._ready.all():
            raise ResetNeeded("Cannot call step() before calling reset() (on every sub-environment)")
        n = self.num_envs
        a = check_action_array(actions, (n, self.task.act_dim), "actions")
        batch = self.batch
        mode = self.autoreset_mode
        pending = self._pending
        restart = pending.any()
        if restart and mode is AutoresetMode.DISABLED:
            raise RuntimeError("autoreset_mode=DISABLED: reset the finished sub-environments with "
                               "reset(options={'reset_mask': mask}) before stepping them again")
        next_step = restart and mode is AutoresetMode.NEXT_STEP
        rows = np.flatnonzero(~pending) if next_step else self._all
        bad = batch.act(rows, np.ascontiguousarray(a[rows]) if next_step else a)
        if bad >= 0:
            raise ValueError(f"actions must be finite, got row {rows[bad]}: {a[rows[bad]]!r}")
        batch.step(rows)
        buf = batch.buf
        terminated = buf.status != 0
        # As gym.make's TimeLimit: truncated at the time limit whether or not the episode also terminated.
        truncated = buf.steps >= self.max_episode_steps if self.max_episode_steps else np.zeros(n, dtype=np.bool_)
        reward = buf.reward.copy()
        final: dict[str, Any] = {}
        reset_rows = None
        if next_step:
            # Sub-envs that ended at the last step are reset instead of stepped (as SyncVectorEnv does).
            reset_rows = np.flatnonzero(pending)
            batch.reset(reset_rows)
            terminated[reset_rows] = False
            truncated[reset_rows] = False
            reward[reset_rows] = 0.0
        done = terminated | truncated
        if mode is AutoresetMode.SAME_STEP and done.any():
            reset_rows = np.flatnonzero(done)
            final_obs = np.full(n, None, dtype=object)
            for i in reset_rows.tolist():
                final_obs[i] = buf.obs32[i].copy()
            final = {"final_obs": final_obs, "_final_obs": done.copy(),
                     "final_info": batch.batch_info(done.copy()), "_final_info": done.copy()}
            batch.reset(reset_rows)
            self._pending[:] = False
        else:
            self._pending[:] = done
        infos = batch.batch_info()
        if reset_rows is not None:
            self._add_params(infos, reset_rows)
        infos.update(final)
        if self.render_mode == "human":
            self.render()
        return buf.obs32.copy(), reward, terminated, truncated, infos

    def render(self) -> tuple[NDArray[np.uint8], ...] | None:
        """``rgb_array``: one frame per sub-environment (drawn by the single env's renderer);
        ``human``: shows sub-environment 0 and returns None."""
        proto = self._proto
        if self.render_mode != "rgb_array":
            return proto.render()  # type: ignore[return-value]
        frames = [proto._render_frame(i) for i in range(self.num_envs)]
        return tuple(f for f in frames if f is not None)

    def close_extras(self, **kwargs: Any) -> None:
        self._proto.close()

    # ------------------------------------------------------------------ SyncVectorEnv-style helpers
    @property
    def np_random_seed(self) -> tuple[int | None, ...]:  # type: ignore[override]
        """The seeds the sub-environments' streams were last seeded with (None: entropy), like ``SyncVectorEnv``."""
        return tuple(self._seeds)

    def get_attr(self, name: str) -> tuple[Any, ...]:
        """An attribute for every sub-environment (shared ones repeated; ``np_random_seed`` per row)."""
        if name == "np_random_seed":
            return self.np_random_seed
        value = getattr(self, name) if hasattr(self, name) else getattr(self._proto, name)
        return (value,) * self.num_envs

    def call(self, name: str, *args: Any, **kwargs: Any) -> tuple[Any, ...]:
        """Call a method once on the batch (the sub-environments share it) or read an attribute;
        the result is repeated for every sub-environment."""
        value = getattr(self, name) if hasattr(self, name) else getattr(self._proto, name)
        result = value(*args, **kwargs) if callable(value) else value
        return (result,) * self.num_envs

    def set_attr(self, name: str, values: Any) -> None:
        """Set an attribute shared by all sub-environments (a list / tuple must hold one value
        per sub-environment, all equal: the batch shares its configuration)."""
        if isinstance(values, list | tuple):
            if len(values) != self.num_envs:
                raise ValueError(f"Values must be a list or tuple with length equal to the number of environments. "
                                 f"Got `{len(values)}` values for {self.num_envs} environments.")
            if any(v is not values[0] and v != values[0] for v in values[1:]):
                raise ValueError(f"{type(self).__name__} sub-environments share attribute {name!r}; "
                                 "per-sub-environment values are not supported")
            values = values[0]
        setattr(self, name, values)

    # ------------------------------------------------------------------ internals
    def _add_params(self, infos: dict[str, Any], rows: NDArray[np.intp]) -> None:
        """The reset info's ``params`` (the new episodes' true parameters) of ``rows``, zeros and a
        False mask elsewhere (as SyncVectorEnv merges it)."""
        params = np.zeros_like(self.batch.buf.params_true)
        params[rows] = self.batch.buf.params_true[rows]
        mask = np.zeros(self.num_envs, dtype=np.bool_)
        mask[rows] = True
        infos["params"] = params
        infos["_params"] = mask


def vector_env_class(env_class: type[ConstraintEnv]) -> type[ConstraintVectorEnv]:
    """The native vector version of a task's environment class (``FooEnv`` -> ``FooVectorEnv``).

    A task module defines its single environment only; this makes the vector class once and puts it
    in that module under its name (so it pickles and imports like a class written there), unless the
    module already defines one.
    """
    module = sys.modules[env_class.__module__]
    name = env_class.__name__.removesuffix("Env") + "VectorEnv"
    existing = getattr(module, name, None)
    if isinstance(existing, type) and issubclass(existing, ConstraintVectorEnv) and existing.env_class is env_class:
        return existing
    cls = type(name, (ConstraintVectorEnv,), {
        "env_class": env_class, "__module__": env_class.__module__,
        "__doc__": f"The native vector version of :class:`{env_class.__name__}`: ``num_envs`` episodes in one batch."})
    setattr(module, name, cls)
    return cls
