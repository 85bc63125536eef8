"""A batch of episodes of one task as arrays, and the compiled kernels that reset and step it.

`Batch` is what both environment classes run on: a single environment is a batch of one,
a native vector environment a batch of ``num_envs``.  Both therefore run the same compiled code,
row for row, and a vector environment equals ``num_envs`` single ones seeded alike, bit for bit.
"""

from __future__ import annotations

import sys
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from vnhc_gym import rng as _random_kernels
from vnhc_gym.envs import episode
from vnhc_gym.envs.episode import STATUS_NONFINITE, Buffers, accept_actions, step_config
from vnhc_gym.mechanics import numerics as _mechanics_kernels
from vnhc_gym.mechanics.cache import load_module
from vnhc_gym.mechanics.codegen import fill_template, module_key
from vnhc_gym.rng import entropy_states, seed_states

if TYPE_CHECKING:
    from vnhc_gym.tasks.base import Task

__all__ = ["Batch", "step_module"]

_TEMPLATE = Path(__file__).with_name("_step_template.py")


def step_module(task: Task) -> ModuleType:
    """The generated step and reset kernels of ``task`` (its system module and its hooks).

    The key hashes the system module's name (itself a hash of the system), the task module's and
    the episode kernels' text, and the template, so an edit of any of them compiles anew.
    """
    system = task.model.compiled.__name__
    hooks = type(task).__module__
    hooks_file = sys.modules[hooks].__file__ or ""
    sources: list[str | Path] = [_TEMPLATE, hooks_file, episode.__file__ or "", _random_kernels.__file__ or "",
                                 _mechanics_kernels.__file__ or ""]
    key = module_key(["step", system, hooks], sources)
    block = (f"from {hooks} import draw, observe\n"
             f"from {system} import N, _aux, _phi, rk4_held_row, rk4_row, work\n\n"
             f"DRAW_STAGES = {int(task.draw_stages)}\nMISMATCH_STAGE = {int(task.mismatch_stage)}\n")
    return load_module(key, lambda: fill_template(_TEMPLATE, "bindings", block, f"task {task.name!r}"),
                       label=f"the {task.name} environment", required=("step", "step_feedback", "reset"))


def entry_point(dispatcher: Any, *args: Any) -> Any:
    """The compiled entry point of a numba ``dispatcher`` for the types of ``args`` (compiling it if
    needed).

    Why: a call through the dispatcher finds the argument types first, which costs about 0.1 us
    per array of a named bundle (2-3 us a step for [`Buffers`][vnhc_gym.envs.episode.Buffers], more
    than the physics of a single environment).  A batch's bundles keep their types for its whole
    life, so it resolves the entry point once and calls it directly.  Only call the result with
    arguments of the same types.
    """
    types = tuple(dispatcher.typeof_pyval(a) for a in args)
    if types not in dispatcher.overloads:
        dispatcher.compile(types)
    return dispatcher.overloads[types].entry_point


class Batch:
    """``n`` episodes of one configured task.

    Parameters
    ----------
    task : Task
        The configured task; its ``model``, ``nominal``, ``args`` and step configuration are read once.
    n : int
        Number of episodes (rows).

    Attributes
    ----------
    buf : Buffers
        Every array, row ``r`` being episode ``r`` (read them; the kernels write them).
    cfg : StepConfig
        The step's scalars.
    """

    def __init__(self, task: Task, n: int) -> None:
        model = task.model
        task.check_sizes()  # before any kernel writes the buffers sized from these declarations
        self.task = task
        self.n = int(n)
        self.buf = Buffers.allocate(self.n, model.n, model.m, len(model.param_names), len(model.output_names),
                                    task.obs_dim)
        self.buf.params_true[:] = task.nominal
        self.buf.params_nominal[:] = task.nominal
        self.cfg = step_config(task)
        self.feedback = "open"
        self.seeded = np.zeros(self.n, dtype=np.bool_)
        self._reasons = np.array(task.all_reasons, dtype=object)
        self._bind()

    def _bind(self) -> None:
        """Load the task's kernels and resolve their entry points for this batch's bundles."""
        self.step_kernels = k = step_module(self.task)
        rows = np.zeros(1, dtype=np.intp)
        self._step = entry_point(k.step, rows, self.buf, self.cfg, self.task.args)
        self._reset = entry_point(k.reset, rows, self.buf, self.cfg, self.task.args)
        self._act = entry_point(accept_actions, rows, np.zeros((1, self.task.act_dim)), self.cfg.bound, self.buf.force,
                             self.buf.action)
        self._act32: Any = None  # the float32 variant, resolved on the first float32 actions
        self._step_feedback: Any = None  # the step with the law in the loop, resolved on first use

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        for name in ("step_kernels", "_step", "_step_feedback", "_reset", "_act", "_act32"):
            state[name] = None  # compiled code: loaded again from the cache
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._bind()

    # ------------------------------------------------------------------ episodes
    def seed(self, rows: NDArray[np.intp], seeds: list[int | None]) -> None:
        """Seed the streams of ``rows``: ``seeds[k]`` for ``rows[k]`` (an int >= 0), or ``None`` to keep
        the row's stream (fresh operating-system entropy if it was never seeded)."""
        given = np.array([s is not None for s in seeds], dtype=np.bool_)
        if given.any():
            self.buf.rng[rows[given]] = seed_states([s for s in seeds if s is not None])
        fresh = rows[~given & ~self.seeded[rows]]
        if fresh.size:
            self.buf.rng[fresh] = entropy_states(fresh.size)
        self.seeded[rows] = True

    def reset(self, rows: NDArray[np.intp]) -> None:
        """Start new episodes in ``rows`` (seed them first, or they draw from entropy)."""
        if not self.seeded[rows].all():
            self.seed(rows, [None] * rows.size)
        self._reset(rows, self.buf, self.cfg, self.task.args)

    def act(self, rows: NDArray[np.intp], actions: NDArray[np.floating]) -> int:
        """Store the actions ``(len(rows), m)`` (C-contiguous float64 or float32) of ``rows`` as forces;
        the index of the first non-finite row (nothing stored), or -1."""
        if actions.dtype == np.float32 and actions.flags.c_contiguous:
            if self._act32 is None:
                self._act32 = entry_point(accept_actions, rows, actions, self.cfg.bound, self.buf.force,
                                          self.buf.action)
            return int(self._act32(rows, actions, self.cfg.bound, self.buf.force, self.buf.action))
        a = np.ascontiguousarray(actions, dtype=np.float64)  # the entry point takes exactly this type
        return int(self._act(rows, a, self.cfg.bound, self.buf.force, self.buf.action))

    def step(self, rows: NDArray[np.intp]) -> None:
        """Advance the episodes ``rows`` by one control period with their stored forces."""
        if self.feedback == "open":
            self._step(rows, self.buf, self.cfg, self.task.args)
            return
        if self._step_feedback is None:
            self._step_feedback = entry_point(self.step_kernels.step_feedback, rows, self.buf, self.cfg, self.task.args)
        self._step_feedback(rows, self.buf, self.cfg, self.task.args)

    def set_feedback(self, feedback: str = "open", gains: Any = 1.0) -> None:
        """Run the geometric law inside the integrator, on top of the held force.

        ``"continuous"`` re-evaluates ``u*`` (with the *nominal* parameters and the true state) at
        every RK4 stage, ``"sampled"`` once per control period; ``"open"`` (default) turns it off.
        The total force is clipped to the force bound at every stage.
        """
        self.cfg = step_config(self.task, feedback, gains)
        self.feedback = feedback

    # ------------------------------------------------------------------ infos
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
            "time": int(buf.steps[r]) * self.cfg.dt,
        }
        if reset:
            info["params"] = buf.params_true[r].copy()
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
        state = np.where(nonfinite[:, None], buf.next_state, buf.state) if nonfinite.any() else buf.state.copy()
        values = {"phi": buf.phi.copy(), "abs_phi": buf.abs_phi.copy(), "abs_phi_sf": buf.abs_phi_sf.copy(),
                  "state": state, "force": buf.force_applied.copy(), "time": buf.steps * self.cfg.dt}
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
