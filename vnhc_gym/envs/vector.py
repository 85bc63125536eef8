"""Native vector versions of the environments: one batched task, one kernel call per step.

``FlockingAlignVectorEnv(num_envs, **kwargs)`` and ``USVStreamVectorEnv(num_envs, **kwargs)``
(also ``gym.make_vec(id, num_envs=N, vectorization_mode="vector_entry_point", **kwargs)``) hold
*one* :class:`~vnhc_gym.envs.task.ConstraintTask` with ``B = num_envs`` rows, built by the same
task class from the same validated arguments as the single environment.  They reproduce
``gymnasium.vector.SyncVectorEnv`` over ``num_envs`` single environments made with
``gym.make(id, max_episode_steps=..., **kwargs)`` exactly: observations, rewards, terminations,
truncations and infos (Gymnasium's dict-of-arrays convention with ``_key`` masks), in both
``AutoresetMode.NEXT_STEP`` (default) and ``AutoresetMode.SAME_STEP`` (``final_obs`` /
``final_info``), and ``AutoresetMode.DISABLED`` (reset finished sub-envs yourself with
``reset(options={"reset_mask": mask})``).  ``reset(seed=s)`` seeds sub-env ``i`` with ``s + i``
like ``SyncVectorEnv`` does.

A step costs a constant number of numpy / numba calls whatever ``num_envs`` is, resets
included: every sub-environment draws its episodes from its own SplitMix64 stream inside the
compiled kernels (:mod:`vnhc_gym.envs._random`), seeded like the single env's.
"""

from __future__ import annotations

import inspect
import sys
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
from gymnasium.error import Error, ResetNeeded
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space
from numba import njit
from numpy.typing import NDArray

from vnhc_gym import MAX_EPISODE_STEPS
from vnhc_gym.envs.flocking_align import FlockingAlignEnv, FlockingTask
from vnhc_gym.envs.task import REASONS, STATUS_OK, ConstraintTask
from vnhc_gym.envs.usv_stream import USVStreamEnv, USVTask

__all__ = ["ConstraintVectorEnv", "FlockingAlignVectorEnv", "USVStreamVectorEnv"]

#: ``termination_reason`` by status code (``REASONS``; None for ``STATUS_OK``), for ``take``.
_REASON_TABLE = np.array([REASONS.get(code) for code in range(max(REASONS) + 1)], dtype=object)


@njit(cache=True)
def accept_actions(actions: np.ndarray, skip: np.ndarray, bound: np.ndarray, force: np.ndarray,
                   action_out: np.ndarray) -> int:
    """Batched :func:`~vnhc_gym.envs.task.check_action`.

    Returns the first row (not ``skip``-ped) with a non-finite entry and writes nothing, or -1
    after writing ``action_out[r] = clip(actions[r], -1, 1)`` (the applied action, charged by
    the action cost) and ``force[r] = action_out[r] * bound[r]`` (zeros for skipped rows, whose
    action is ignored).  ``actions``, ``bound`` (the force bound tiled over the rows), ``force``
    and ``action_out`` have the same shape and are C-contiguous.
    """
    n, m = actions.shape
    flat = actions.reshape(-1)  # C-contiguous (see ConstraintVectorEnv.step)
    finite = True
    for i in range(flat.shape[0]):  # a branch-free (vectorised) test first: x - x is NaN for NaN, inf
        finite &= (flat[i] - flat[i]) == 0.0
    if not finite:
        for r in range(n):
            if skip[r]:
                continue
            for j in range(m):
                if not np.isfinite(actions[r, j]):
                    return r
    # Flat loops over all entries (vectorised); a loop per row over m entries is not.
    bd = bound.reshape(-1)
    fo = force.reshape(-1)
    ao = action_out.reshape(-1)
    for i in range(flat.shape[0]):
        a = min(max(flat[i], -1.0), 1.0)
        fo[i] = a * bd[i]
        ao[i] = a
    for r in range(n):
        if skip[r]:
            for j in range(m):
                fo[r * m + j] = 0.0
                ao[r * m + j] = 0.0
    return -1


@njit(cache=True)
def step_outcome(status: np.ndarray, steps: np.ndarray, max_steps: int, terminated: np.ndarray,
                 truncated: np.ndarray, ended: np.ndarray) -> int:
    """``terminated = status != OK``, ``truncated = steps >= max_steps`` (never if
    ``max_steps <= 0``) and ``ended = terminated | truncated``; returns the number of ended rows."""
    n_ended = 0
    for r in range(status.shape[0]):
        term = status[r] != STATUS_OK
        trunc = max_steps > 0 and steps[r] >= max_steps
        terminated[r] = term
        truncated[r] = trunc
        ended[r] = term or trunc
        if term or trunc:
            n_ended += 1
    return n_ended


@njit(cache=True)
def restart_outcome(rows: np.ndarray, reset_mask: np.ndarray, terminated: np.ndarray, truncated: np.ndarray,
                    pending: np.ndarray, reward: np.ndarray) -> int:
    """The outcome of sub-envs ``rows`` that ``NEXT_STEP``-reset at this step: marked in
    ``reset_mask``, not terminated, truncated or pending, reward 0.  Returns the number of
    sub-envs still pending (ended at this step)."""
    for i in range(rows.shape[0]):
        r = rows[i]
        reset_mask[r] = True
        terminated[r] = False
        truncated[r] = False
        pending[r] = False
        reward[r] = 0.0
    return int(np.count_nonzero(pending))


def _check_seed(seed: Any) -> None:
    """The single env's seed rule (``gymnasium.utils.seeding.np_random``): an int >= 0."""
    if not isinstance(seed, int):
        raise Error(f"Seed must be a python integer, actual type: {type(seed)}")
    if seed < 0:
        raise Error(f"Seed must be greater or equal to zero, actual value: {seed}")


class _RowView:
    """Row ``i`` of a batched task seen as a ``B = 1`` task, for the single env's ``render``."""

    ROW_ARRAYS = frozenset({"state", "next_state", "phi", "aux", "obs", "obs32", "params_true", "params_nominal",
                            "force", "force_applied", "action", "reward", "abs_phi", "status", "steps"})

    def __init__(self, task: ConstraintTask, i: int) -> None:
        self._task = task
        self._i = i

    def __getattr__(self, name: str) -> Any:
        value = getattr(self._task, name)
        if name in self.ROW_ARRAYS:
            return value[self._i: self._i + 1]
        return value

    def current_params(self, i: int) -> dict[str, float]:
        return self._task.current_params(self._i + i)  # type: ignore[attr-defined]


class ConstraintVectorEnv(VectorEnv):
    """Shared implementation of the native vector environments (see the module docstring).

    Parameters
    ----------
    num_envs : int
        Number of sub-environments (rows of the batched task).
    max_episode_steps : int or None
        Truncation after this many steps of a sub-environment's episode, like ``gym.make``'s
        ``TimeLimit`` (default ``vnhc_gym.MAX_EPISODE_STEPS``, 400; None: never truncate).
    autoreset_mode : AutoresetMode or str
        ``NEXT_STEP`` (default), ``SAME_STEP`` or ``DISABLED``, as in ``SyncVectorEnv``.
    **kwargs
        Every keyword argument of the single environment (``scenario``, ``render_mode``, ...),
        validated by the single environment's own constructor.

    Attributes
    ----------
    task : ConstraintTask
        The batched task (``task.n == num_envs``); ``task.set_feedback(...)`` acts on all rows.
    """

    single_env_cls: ClassVar[type[gym.Env]]
    task_cls: ClassVar[type[ConstraintTask]]
    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["human", "rgb_array"], "render_fps": 20,  # type: ignore[misc]
                                          "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(self, num_envs: int = 1, *, max_episode_steps: int | None = MAX_EPISODE_STEPS,
                 autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP, **kwargs: Any) -> None:
        if isinstance(num_envs, bool) or not isinstance(num_envs, int | np.integer) or num_envs < 1:
            raise ValueError(f"num_envs must be an integer >= 1, got {num_envs!r}")
        if max_episode_steps is not None and (isinstance(max_episode_steps, bool) or not isinstance(
                max_episode_steps, int | np.integer) or max_episode_steps < 1):
            raise ValueError(f"max_episode_steps must be an integer >= 1 or None, got {max_episode_steps!r}")
        try:
            mode = autoreset_mode if isinstance(autoreset_mode, AutoresetMode) else AutoresetMode(autoreset_mode)
        except ValueError:
            raise ValueError(f"autoreset_mode must be one of {[m.value for m in AutoresetMode]}, "
                             f"got {autoreset_mode!r}") from None
        n = int(num_envs)
        # The single env's constructor validates every argument (same errors as gym.make); the
        # batched task is then built by the same task class from the same arguments.
        self._proto = self.single_env_cls(**kwargs)
        task_args = [p.name for p in inspect.signature(self.task_cls.__init__).parameters.values()
                     if p.kind is inspect.Parameter.KEYWORD_ONLY]
        proto_task: ConstraintTask = self._proto.task  # type: ignore[attr-defined]
        self.task: ConstraintTask = self.task_cls(proto_task.config, n,  # type: ignore[call-arg, arg-type]
                                                  **{k: v for k, v in kwargs.items() if k in task_args})
        if not (np.array_equal(self.task.params_nominal[0], proto_task.params_nominal[0])
                and np.array_equal(self.task.force_bound, proto_task.force_bound)
                and self.task.obs_dim == proto_task.obs_dim):  # pragma: no cover - guards future drift
            raise RuntimeError(f"{type(self).__name__}: the batched task does not match the single env's")
        self._proto.task = self.task  # type: ignore[attr-defined]  # its render() draws row 0 of the batch

        self.num_envs = n
        self.max_episode_steps = None if max_episode_steps is None else int(max_episode_steps)
        self.autoreset_mode = mode
        self.metadata = {**type(self).metadata, **self._proto.metadata, "autoreset_mode": mode}  # type: ignore[misc]
        self.render_mode = self._proto.render_mode
        self.config = self.task.config
        self.scenario = kwargs.get("scenario", "nominal")
        self.single_observation_space = self._proto.observation_space
        self.single_action_space = self._proto.action_space
        self.observation_space = batch_space(self.single_observation_space, n)
        self.action_space = batch_space(self.single_action_space, n)
        self._act_shape = (n, *self.single_action_space.shape)  # type: ignore[misc]
        self._bound = np.tile(self.task.force_bound, (n, 1))  # per entry: accept_actions' flat loop
        self._dt = self.task.config.dt
        self._unreset = np.ones(n, dtype=np.bool_)  # sub-envs never reset yet (stepping them is an error)
        self._ready = False
        self._seeds: list[int | None] = [None] * n
        self._autoreset = np.zeros(n, dtype=np.bool_)  # sub-envs whose episode ended at the last step
        self._n_pending = 0
        self._max_steps = 0 if max_episode_steps is None else int(max_episode_steps)
        self._true = np.ones(n, dtype=np.bool_)
        self._no_skip = np.zeros(n, dtype=np.bool_)

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
            _check_seed(int(seed))
            seeds = [int(seed) + i for i in range(n)]
        else:
            seeds = list(seed)  # type: ignore[arg-type]
            if len(seeds) != n:
                raise ValueError(f"If seeds are passed as a list the length must match num_envs={n} "
                                 f"but got length={len(seeds)}.")
            for s in seeds:
                if s is not None:
                    _check_seed(s)
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
        rows = np.arange(n) if mask is None else np.flatnonzero(mask)
        row_seeds = [seeds[i] for i in rows.tolist()]
        for i, s in zip(rows.tolist(), row_seeds, strict=True):
            if s is not None or not self.task._seeded[i]:
                self._seeds[i] = s
        self.task.seed_rows(rows, row_seeds)
        self.task.reset_rows(rows)
        self._autoreset[rows] = False
        self._n_pending = int(np.count_nonzero(self._autoreset))
        self._unreset[rows] = False
        self._ready = not self._unreset.any()
        obs, infos = self._infos(None if mask is None else mask.copy())
        self._add_params(infos, np.ones(n, dtype=np.bool_) if mask is None else mask.copy())
        if self.render_mode == "human":
            self.render()
        return obs, infos

    def step(self, actions: Any) -> tuple[NDArray[np.float32], NDArray[np.float64], NDArray[np.bool_],
                                          NDArray[np.bool_], dict[str, Any]]:
        """Step every sub-environment; actions ``(num_envs, act_dim)`` in ``[-1, 1]`` (clipped).

        Raises ``ValueError`` (and changes nothing) for a wrong shape or a non-finite row.
        """
        if not self._ready:
            raise ResetNeeded("Cannot call step() before calling reset() (on every sub-environment)")
        a = actions if isinstance(actions, np.ndarray) else np.asarray(actions, dtype=np.float64)
        if a.shape != self._act_shape:
            raise ValueError(f"actions must have shape {self._act_shape}, got {a.shape}")
        if a.dtype != np.float64 and a.dtype != np.float32:
            if a.dtype.kind not in "fiub":
                raise ValueError(f"actions must be real numbers, got dtype {a.dtype}")
            a = a.astype(np.float64)
        if not a.flags.c_contiguous:
            a = np.ascontiguousarray(a)
        task = self.task
        mode = self.autoreset_mode
        n_pending = self._n_pending
        if n_pending and mode is AutoresetMode.DISABLED:
            raise RuntimeError("autoreset_mode=DISABLED: reset the finished sub-environments with "
                               "reset(options={'reset_mask': mask}) before stepping them again")
        next_step = n_pending > 0 and mode is AutoresetMode.NEXT_STEP
        pending = self._autoreset
        bad = accept_actions(a, pending if next_step else self._no_skip, self._bound, task.force, task.action)
        if bad >= 0:
            raise ValueError(f"actions must be finite, got row {bad}: {a[bad]!r}")
        # The step's own pass fills the info copies (rows reset below are copied again after).
        bufs = task.info_buffers()
        if next_step:
            rows = np.flatnonzero(pending)
            # These rows are only reset this step (their step is discarded): they draw nothing.
            status = task.step(pending, info=bufs)
        else:
            status = task.step(info=bufs)
        n = self.num_envs
        terminated = np.empty(n, dtype=np.bool_)
        truncated = np.empty(n, dtype=np.bool_)
        self._n_pending = step_outcome(status, task.steps, self._max_steps, terminated, truncated, pending)
        reward = task.reward.copy()
        final: dict[str, Any] | None = None
        reset_mask = None
        if next_step:
            task.reset_rows(rows, bufs)
            reset_mask = np.zeros(n, dtype=np.bool_)
            self._n_pending = restart_outcome(rows, reset_mask, terminated, truncated, pending, reward)
        elif self._n_pending and mode is AutoresetMode.SAME_STEP:
            done = pending.copy()
            rows = np.flatnonzero(done)
            final_obs = np.full(n, None, dtype=object)
            for i in rows.tolist():
                final_obs[i] = task.obs32[i].copy()
            # The step's info, before the reset (copies: bufs gets the reset rows' infos below).
            step_info = task.info_from(tuple(b.copy() for b in bufs))
            final = {"final_obs": final_obs, "_final_obs": done, "final_info": self._infos(done.copy(), step_info)[1],
                     "_final_info": done.copy()}
            task.reset_rows(rows, bufs)
            reset_mask = done
        obs, infos = self._infos(info=task.info_from(bufs))
        if reset_mask is not None:
            self._add_params(infos, reset_mask, rows)
        if final is not None:
            infos.update(final)
        if self.render_mode == "human":
            self.render()
        return obs, reward, terminated, truncated, infos

    def render(self) -> tuple[NDArray[np.uint8], ...] | None:
        """``rgb_array``: one frame per sub-environment (drawn by the single env's renderer);
        ``human``: shows sub-environment 0 and returns None."""
        proto: Any = self._proto
        if self.render_mode != "rgb_array":
            return proto.render()
        frames = []
        try:
            for i in range(self.num_envs):
                proto.task = _RowView(self.task, i)
                frames.append(proto.render())
        finally:
            proto.task = self.task
        return tuple(frames)

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
            return getattr(self, name)
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
    def _infos(self, rows: NDArray[np.bool_] | None = None, info: tuple[NDArray[np.float32], dict[str, Any], int]
               | None = None) -> tuple[NDArray[np.float32], dict[str, Any]]:
        """A copy of the observations and the batched info of all rows (or of ``rows``: zeros
        and False masks elsewhere), as ``SyncVectorEnv`` assembles the single envs' ``info``;
        from ``info`` (``task.info_from``) if given, else from ``task.batch_info()``."""
        task = self.task
        status = task.status
        obs, values, n_bad = task.batch_info() if info is None else info
        infos: dict[str, Any] = {}
        if rows is None:
            true = self._true
            for key, value in values.items():
                infos[key] = value
                infos["_" + key] = true.copy()
            ended = status != STATUS_OK if n_bad else None
        else:
            off = ~rows
            for key, value in values.items():
                value[off] = 0
                infos[key] = value
                infos["_" + key] = rows.copy()
            ended = (status != STATUS_OK) & rows if n_bad else None
        if ended is not None and ended.any():
            # None where OK (every row that has no reason, masked-off rows included).
            infos["termination_reason"] = _REASON_TABLE.take(status if rows is None else np.where(rows, status, 0))
            infos["_termination_reason"] = ended
        return obs, infos

    def _add_params(self, infos: dict[str, Any], rows: NDArray[np.bool_], idx: NDArray[np.intp] | None = None
                    ) -> None:
        """The reset info's ``params`` (the new episodes' true parameters) for the sub-envs in
        ``rows`` (``idx``: the same as indices, if known) that were just reset (zeros and a False
        mask elsewhere, as SyncVectorEnv merges it)."""
        buf = self.__dict__.get("_params_buf")
        if idx is None:
            idx = np.flatnonzero(rows)
        # Refill the last call's array if nobody else holds it (references: the tuple and
        # getrefcount's argument): a fresh (n, n_params) array every step page-faults at large n.
        # Integer rows, not the mask: a few reset rows of a big batch are a few row copies.
        if buf is not None and sys.getrefcount(buf[0]) <= 2:
            params, last = buf
            params[last] = 0.0
        else:
            params = np.zeros_like(self.task.params_true)
        params[idx] = self.task.params_true[idx]
        self._params_buf = (params, idx)
        infos["params"] = params
        infos["_params"] = rows


class FlockingAlignVectorEnv(ConstraintVectorEnv):
    """``num_envs`` copies of :class:`~vnhc_gym.envs.flocking_align.FlockingAlignEnv` in one batch."""

    single_env_cls = FlockingAlignEnv
    task_cls = FlockingTask


class USVStreamVectorEnv(ConstraintVectorEnv):
    """``num_envs`` copies of :class:`~vnhc_gym.envs.usv_stream.USVStreamEnv` in one batch."""

    single_env_cls = USVStreamEnv
    task_cls = USVTask
