"""A batch of episodes of one task, run by the task's pure JAX functions, with numpy at the boundary.

`Batch` is what both environment classes run on: a single environment is a batch of one, a native
vector environment a batch of ``num_envs``.  Both call the same compiled program, row for row, so a
vector environment equals ``num_envs`` single ones seeded alike, bit for bit.

The program is [`FunctionalEnv`][vnhc_gym.envs.functional.FunctionalEnv]'s ``initial`` and
``transition`` (the step every task shares, around the task's own functions), batched with
``jax.vmap`` and compiled with ``jax.jit`` in float64 (inside ``jax.enable_x64``, so a user's global
JAX settings stay as they are).  Each episode's whole memory is one float64 row (its state, true and
nominal parameters, observation, and the last step's outputs) and one random key; a step or a reset
is one compiled call over all rows, with a mask of the rows it acts on.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import TYPE_CHECKING, Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree
from numpy.typing import NDArray

from vnhc_gym.envs.functional import FEEDBACK, Actuator, EnvParams, EnvState, FunctionalEnv

if TYPE_CHECKING:
    from vnhc_gym.tasks.base import Task

__all__ = ["Batch", "Buffers", "seed_keys"]

STATUS_NONFINITE = 1  #: the state (or phi, or the observation) was not finite: the row kept its last finite state

#: The fields of an episode's memory row, in order, and their sizes in terms of the task's dimensions
#: (``n2`` state entries, ``P`` parameters, ``d`` observation entries, ``m`` controls).
_FIELDS = (("state", "n2"), ("params_true", "P"), ("params_nominal", "P"), ("obs", "d"), ("steps", 1),
           ("reward", 1), ("status", 1), ("phi", "m"), ("abs_phi", 1), ("abs_phi_sf", 1), ("force_applied", "m"),
           ("next_state", "n2"), ("queue", "Qm"), ("lagged", "A"), ("hidden", "H"), ("switch_at", "S"))


class Buffers(NamedTuple):
    """The arrays of ``B`` episodes (row ``r`` is episode ``r``): views of the batch's memory, kept
    current by every call."""

    state: NDArray[np.float64]  #: (B, 2n) the state (q, qd): the last finite one
    next_state: NDArray[np.float64]  #: (B, 2n) the state RK4 reached (not finite at a non-finite end)
    params_true: NDArray[np.float64]  #: (B, n_params) the parameters that drive the dynamics
    params_nominal: NDArray[np.float64]  #: (B, n_params) the parameters a controller is told
    force_applied: NDArray[np.float64]  #: (B, m) the applied force, averaged over the substeps
    phi: NDArray[np.float64]  #: (B, m) phi at the state, with the true parameters
    obs: NDArray[np.float64]  #: (B, d) the observation (float64)
    obs32: NDArray[np.float32]  #: (B, d) the observation the environment returns
    reward: NDArray[np.float64]  #: (B,)
    abs_phi: NDArray[np.float64]  #: (B,) mean_b |phi^b|
    abs_phi_sf: NDArray[np.float64]  #: (B,) mean_b |phi~^b|
    status: NDArray[np.int64]  #: (B,) 0, `STATUS_NONFINITE`, or 1 + the index of a task's reason
    steps: NDArray[np.int64]  #: (B,) steps since the episode's start
    queue: NDArray[np.float64]  #: (B, Q m) the commands not yet applied, newest first (a delay)
    lagged: NDArray[np.float64]  #: (B, m) the actuator's force (a lag); empty columns without hidden structure
    hidden: NDArray[np.float64]  #: (B, 2 H) the two draws of the hidden quantities (`EnvState.actuator`)
    switch_at: NDArray[np.float64]  #: (B, 1) the step from which the second draw is in force


def seed_keys(seeds: list[int]) -> NDArray[np.uint32]:
    """JAX's ``PRNGKey(seed)`` for each seed (``0 <= seed < 2**64``), as a ``(k, 2)`` uint32 array:
    the seed's high and low 32 bits (threefry's key), computed here without a call into JAX."""
    s = np.array(seeds, dtype=np.uint64)
    return np.stack([(s >> np.uint64(32)).astype(np.uint32), (s & np.uint64(0xFFFFFFFF)).astype(np.uint32)], axis=1)


class _Program(NamedTuple):
    """The compiled reset and step of one task shape (shared by every batch of that shape)."""

    reset: Callable[..., Any]
    step: Callable[..., Any]
    unravel: Callable[[Any], EnvParams]


_PROGRAMS: dict[Any, _Program] = {}

#: Rows are padded to a multiple of this (the float64 lanes of the widest vector unit, AVX-512).
_LANES = 8


def _program(env: FunctionalEnv, params: EnvParams, widths: dict[str, int]) -> _Program:
    """The compiled functions of ``env``, for parameters of the structure of ``params``.

    The parameters are an argument (one flat float64 vector), not constants of the program, so every
    scenario, control period and noise level of a task shares one compilation.  The key is what the
    program's code depends on: the task's functions and declarations, the loop count, the reward
    shape, the feedback mode and the parameters' structure.
    """
    t = env.task
    leaves, treedef = jax.tree.flatten(params)
    functions = tuple(function_identity(f) for f in (t.initial, t.observation, t.terminations, t.task_params,
                                                     t.scale_free, t.unmodelled))
    key = (functions, t.system, t.reasons, t.unmodelled_ranges, env.delay_slots, env.structural,
           t.limits, t.impulse_mask, t.uncertain, t.obs_dim, env.substeps, env.reward, env.feedback, treedef,
           tuple((np.shape(x), np.result_type(x).str) for x in leaves), params.max_steps_in_episode)
    program = _PROGRAMS.get(key)
    if program is not None:
        return program
    with jax.enable_x64(True):
        _, unravel = ravel_pytree(params)
    system = t.system
    offsets = np.cumsum([0] + list(widths.values()))
    where = {name: slice(int(offsets[i]), int(offsets[i + 1])) for i, name in enumerate(widths)}

    m = env.num_actions

    def unpack(row: jax.Array) -> EnvState:
        actuator = None
        if env.structural:
            actuator = Actuator(queue=row[where["queue"]].reshape(env.queue_length, m), lagged=row[where["lagged"]],
                                hidden=row[where["hidden"]].reshape(2, env.n_hidden),
                                switch_at=row[where["switch_at"]][0])
        return EnvState(s=row[where["state"]], p=row[where["params_true"]], p_nominal=row[where["params_nominal"]],
                        obs=row[where["obs"]], time=row[where["steps"]][0].astype(jnp.int32), actuator=actuator)

    def pack(actuator: Actuator | None) -> list[jax.Array]:
        if actuator is None:
            return []
        return [actuator.queue.reshape(-1), actuator.lagged, actuator.hidden.reshape(-1), actuator.switch_at[None]]

    def reset_row(key: jax.Array, p: EnvParams) -> tuple[jax.Array, jax.Array]:
        key, k_reset = jax.random.split(key)
        obs, st = env.initial(k_reset, p)
        phi = system.phi(st.s, st.p)
        abs_phi_sf = jnp.mean(jnp.abs(env._scale_free(st.s, phi, p)))
        zero_m = jnp.zeros_like(phi)
        row = jnp.concatenate([st.s, st.p, st.p_nominal, obs, jnp.zeros(3), phi, jnp.mean(jnp.abs(phi))[None],
                               abs_phi_sf[None], zero_m, st.s, *pack(st.actuator)])
        return row, key

    def step_row(key: jax.Array, row: jax.Array, action: jax.Array, p: EnvParams) -> tuple[jax.Array, jax.Array]:
        key, k_step = jax.random.split(key)
        new, out = env.transition(k_step, unpack(row), action, p)
        row = jnp.concatenate([new.s, new.p, new.p_nominal, new.obs, new.time.astype(row.dtype)[None],
                               out.reward[None], out.status.astype(row.dtype)[None], out.phi, out.abs_phi[None],
                               out.abs_phi_sf[None], out.force, out.s_reached, *pack(new.actuator)])
        return row, key

    @jax.jit
    def reset(mem: jax.Array, keys: jax.Array, mask: jax.Array, flat: jax.Array) -> tuple[jax.Array, jax.Array]:
        # Only the rows of the mask draw a start: a vector environment resets the few rows that ended
        # on most steps, and a start for every row cost as much as the step.  They are gathered in
        # chunks of an eighth of the batch (a multiple of _LANES rows, so that each row is computed
        # by the same vector code whatever the batch: the bits do not depend on the batch size).
        p = unravel(flat)
        n = mask.shape[0]
        chunk = _LANES * max(1, -(-n // (8 * _LANES)))
        chunks = -(-n // chunk)
        idx = jnp.nonzero(mask, size=chunks * chunk, fill_value=n)[0]  # index n: padding, dropped
        count = jnp.sum(mask, dtype=jnp.int32)

        def draw(carry: tuple[jax.Array, jax.Array, jax.Array]) -> tuple[jax.Array, jax.Array, jax.Array]:
            c, mem, out_keys = carry
            rows = jax.lax.dynamic_slice_in_dim(idx, c * chunk, chunk)
            new, new_keys = jax.vmap(reset_row, in_axes=(0, None))(keys[jnp.minimum(rows, n - 1)], p)
            return c + 1, mem.at[rows].set(new, mode="drop"), out_keys.at[rows].set(new_keys, mode="drop")

        _, mem, keys = jax.lax.while_loop(lambda carry: carry[0] * chunk < count, draw,
                                          (jnp.zeros((), jnp.int32), mem, keys))
        return mem, keys

    @jax.jit
    def step(mem: jax.Array, keys: jax.Array, actions: jax.Array, mask: jax.Array, flat: jax.Array
             ) -> tuple[jax.Array, jax.Array]:
        p = unravel(flat)
        rows, new_keys = jax.vmap(step_row, in_axes=(0, 0, 0, None))(keys, mem, actions, p)
        return jnp.where(mask[:, None], rows, mem), jnp.where(mask[:, None], new_keys, keys)

    program = _PROGRAMS[key] = _Program(reset=reset, step=step, unravel=unravel)
    return program


def function_identity(fn: Any) -> Any:
    """What a task function's code is: the function, or a ``partial``'s function and keywords (a new
    ``partial`` of the same function and system is the same code)."""
    if isinstance(fn, partial):
        return (fn.func, fn.args, tuple(sorted(fn.keywords.items())))
    return fn


class Batch:
    """``n`` episodes of one configured task.

    Parameters
    ----------
    task : Task
        The configured task; its pure functions, declarations and configuration are read once.
    n : int
        Number of episodes (rows).

    Attributes
    ----------
    buf : Buffers
        Every episode's arrays after the last call (the same arrays for the batch's life: its
        fields are views of the batch's memory, and writing a state or a parameter there is what
        the next step starts from).
    env : FunctionalEnv
        The task's environment as pure functions (with the feedback mode of `set_feedback`).
    params : EnvParams
        Its parameters.
    dt : float
        The control period (s).
    seeded : ndarray of bool
        Rows whose random stream was seeded.
    """

    def __init__(self, task: Task, n: int) -> None:
        task.check_sizes()
        self.task = task
        self.n = int(n)
        model = task.model
        hides = task.config.structural  # the columns of the hidden structure are empty without it
        self._widths = {name: (size if isinstance(size, int) else
                               {"n2": 2 * model.n, "P": len(model.param_names), "d": int(task.obs_dim),
                                "m": model.m, "Qm": max(1, task.config.delay_max) * model.m * hides,
                                "A": model.m * hides, "H": 2 * (2 + len(task.unmodelled_ranges)) * hides,
                                "S": int(hides)}[size])
                        for name, size in _FIELDS}
        # Rows are padded to a multiple of _LANES: XLA vectorises the loop over rows and computes
        # the rows left over past a multiple of the vector width with scalar code, whose results
        # differ in the last bit for some functions (the boat's); padded, every episode's row is
        # computed by the same code whatever the batch size, so a batch of any size gives each
        # episode the same bits.  The padding rows are never stepped or shown.
        rows = -(-self.n // _LANES) * _LANES
        self.mem = np.zeros((rows, sum(self._widths.values())))
        self.keys = np.zeros((rows, 2), dtype=np.uint32)
        self.actions = np.zeros((rows, model.m))
        self.seeded = np.zeros(self.n, dtype=np.bool_)
        self.dt = float(task.config.dt)
        self._reasons = np.array(task.all_reasons, dtype=object)
        self.feedback = "open"
        self.set_feedback("open")
        self.buf = self._view()

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        for name in ("env", "params", "_compiled", "buf"):
            state[name] = None  # functions and modules: made (or found compiled) again after unpickling
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self.set_feedback(self.feedback, self._gains)
        self.buf = self._view()  # views of this copy's memory

    def set_feedback(self, feedback: str = "open", gains: Any = 1.0) -> None:
        """Run the geometric law inside the integrator, on top of the held force.

        ``"continuous"`` re-evaluates ``u*`` (with the *nominal* parameters and the true state) at
        every RK4 stage, ``"sampled"`` once per control period; ``"open"`` (default) turns it off.
        The total force is clipped to the force bound at every stage.
        """
        if feedback not in FEEDBACK:
            raise ValueError(f"feedback must be one of {sorted(FEEDBACK)}, got {feedback!r}")
        k = np.asarray(gains, dtype=np.float64)
        if not (np.all(np.isfinite(k)) and np.all(k >= 0)):
            raise ValueError(f"gains must be finite and >= 0, got {gains!r}")
        self.env, self.params = self.task.functional(feedback=feedback, gains=k)
        self._gains = k
        with jax.enable_x64(True):
            self._flat = np.asarray(ravel_pytree(self.params)[0], dtype=np.float64)
        self._compiled = _program(self.env, self.params, self._widths)
        self.feedback = feedback

    # ------------------------------------------------------------------ episodes
    def seed(self, rows: NDArray[np.intp], seeds: list[int | None]) -> None:
        """Seed the streams of ``rows``: ``seeds[k]`` for ``rows[k]`` (an int >= 0), or ``None`` to keep
        the row's stream (fresh operating-system entropy if it was never seeded)."""
        keys = np.array(self.keys)  # writable
        given = np.array([s is not None for s in seeds], dtype=np.bool_)
        if given.any():
            keys[rows[given]] = seed_keys([s for s in seeds if s is not None])
        fresh = rows[~given & ~self.seeded[rows]]
        if fresh.size:
            keys[fresh] = np.random.SeedSequence().generate_state(2 * fresh.size).reshape(-1, 2)
        self.keys = keys
        self.seeded[rows] = True

    def reset(self, rows: NDArray[np.intp]) -> None:
        """Start new episodes in ``rows`` (seed them first, or they draw from entropy)."""
        if not self.seeded[rows].all():
            self.seed(rows, [None] * rows.size)
        with jax.enable_x64(True):
            mem, keys = self._compiled.reset(self.mem, self.keys, self._mask(rows), self._flat)
        self._store(mem, keys)

    def act(self, rows: NDArray[np.intp], actions: NDArray[np.floating]) -> int:
        """Store the actions ``(len(rows), m)`` of ``rows`` (clipped to [-1, 1] by the step); the index
        of the first non-finite row (nothing stored), or -1."""
        bad = np.flatnonzero(~np.isfinite(actions).all(axis=1))
        if bad.size:
            return int(bad[0])
        self.actions[rows] = actions
        return -1

    def step(self, rows: NDArray[np.intp]) -> None:
        """Advance the episodes ``rows`` by one control period with their stored actions."""
        with jax.enable_x64(True):
            mem, keys = self._compiled.step(self.mem, self.keys, self.actions, self._mask(rows), self._flat)
        self._store(mem, keys)

    def _mask(self, rows: NDArray[np.intp]) -> NDArray[np.bool_]:
        mask = np.zeros(self.mem.shape[0], dtype=np.bool_)
        mask[rows] = True
        return mask

    def _store(self, mem: Any, keys: Any) -> None:
        """Copy a call's results into the batch's arrays, in place (so `buf`'s views stay current)."""
        np.copyto(self.mem, np.asarray(mem))
        self.keys = np.array(keys)
        buf = self.buf
        np.copyto(buf.obs32, buf.obs)
        np.copyto(buf.status, self._column("status")[:, 0], casting="unsafe")
        np.copyto(buf.steps, self._column("steps")[:, 0], casting="unsafe")

    def _column(self, name: str) -> NDArray[np.float64]:
        start = 0
        for field, width in self._widths.items():
            if field == name:
                return self.mem[:self.n, start:start + width]
            start += width
        raise KeyError(name)

    def _view(self) -> Buffers:
        """Views of the first ``n`` rows of the memory (and copies, updated by `_store`, of the
        entries whose type differs: the float32 observation, the status and the step count)."""
        c = self._column
        return Buffers(state=c("state"), next_state=c("next_state"), params_true=c("params_true"),
                       params_nominal=c("params_nominal"), force_applied=c("force_applied"), phi=c("phi"),
                       obs=c("obs"), obs32=c("obs").astype(np.float32), reward=c("reward")[:, 0],
                       abs_phi=c("abs_phi")[:, 0], abs_phi_sf=c("abs_phi_sf")[:, 0],
                       status=c("status")[:, 0].astype(np.int64), steps=c("steps")[:, 0].astype(np.int64),
                       queue=c("queue"), lagged=c("lagged"), hidden=c("hidden"), switch_at=c("switch_at"))

    # ------------------------------------------------------------------ infos
    @property
    def hides(self) -> bool:
        """Whether the episodes hide structure (a delay, a lag, unmodelled forces) from the controller."""
        return bool(self.task.config.structural)

    def hidden_now(self, rows: NDArray[np.intp]) -> dict[str, NDArray[np.float64]]:
        """The hidden quantities in force for the next step of ``rows``: ``delay_steps``,
        ``lag_time_constant`` (s; 0: none) and ``unmodelled_coefficients`` (the task's card names them)."""
        buf = self.buf
        draws = buf.hidden[rows].reshape(len(rows), 2, -1)
        later = buf.steps[rows] >= buf.switch_at[rows, 0]
        now = np.where(later[:, None], draws[:, 1], draws[:, 0])
        return {"delay_steps": now[:, 0].astype(np.int64), "lag_time_constant": now[:, 1],
                "unmodelled_coefficients": now[:, 2:].copy()}

    def info(self, r: int, reset: bool = False) -> dict[str, Any]:
        """The documented ``info`` of row ``r`` (fresh copies); ``reset`` adds the episode's true
        parameters ``params`` (constant over an episode, so not repeated at every step)."""
        buf = self.buf
        status = int(buf.status[r])
        info: dict[str, Any] = {
            "phi": buf.phi[r].copy(),
            "abs_phi": float(buf.abs_phi[r]),
            "abs_phi_sf": float(buf.abs_phi_sf[r]),
            "state": (buf.next_state if status == STATUS_NONFINITE else buf.state)[r].copy(),
            "force": buf.force_applied[r].copy(),
            "time": int(buf.steps[r]) * self.dt,
        }
        if reset:
            info["params"] = buf.params_true[r].copy()
        if self.hides:
            now = self.hidden_now(np.array([r]))
            info.update(delay_steps=int(now["delay_steps"][0]), lag_time_constant=float(now["lag_time_constant"][0]),
                        unmodelled_coefficients=now["unmodelled_coefficients"][0])
        if status:
            info["termination_reason"] = self._reasons[status]
        return info

    def batch_info(self, rows: NDArray[np.bool_] | None = None) -> dict[str, Any]:
        """The arrays of `info` stacked over all rows, in Gymnasium's vector convention: each key
        ``k`` with a mask ``_k`` (``rows``, default all; other rows are zero / None there)."""
        buf = self.buf
        n = self.n
        mask = np.ones(n, dtype=np.bool_) if rows is None else rows
        status = buf.status
        nonfinite = status == STATUS_NONFINITE
        state = np.where(nonfinite[:, None], buf.next_state, buf.state)
        values = {"phi": buf.phi.copy(), "abs_phi": buf.abs_phi.copy(), "abs_phi_sf": buf.abs_phi_sf.copy(),
                  "state": state, "force": buf.force_applied.copy(), "time": buf.steps * self.dt}
        if self.hides:
            values.update(self.hidden_now(np.arange(n)))
        infos: dict[str, Any] = {}
        for key, value in values.items():
            if rows is not None:
                value[~rows] = 0
            infos[key] = value
            infos["_" + key] = mask.copy()
        ended = (status != 0) & mask
        if ended.any():
            infos["termination_reason"] = self._reasons.take(np.where(ended, status, 0))
            infos["_termination_reason"] = ended
        return infos
