"""Behaviour shared by the single environments: reset, step, pickling, close.

Each environment file keeps its docstring, its constructor (spaces, task) and its ``render``;
this base class holds the ``reset``/``step`` plumbing around the batched task (``B = 1``).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from numpy.typing import NDArray

from vnhc_gym.envs.task import ConstraintTask, apply_action

__all__ = ["ConstraintEnv"]


class ConstraintEnv(gym.Env[NDArray[np.float32], NDArray[np.float32]]):
    """A Gymnasium env over one row of a :class:`ConstraintTask` (subclasses set ``task``, the
    spaces, ``_bound`` and ``render``)."""

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 20}  # noqa: RUF012 (Gymnasium API)
    task: ConstraintTask
    _bound: NDArray[np.float64]
    _renderer: Any = None

    def _check_render_mode(self, render_mode: str | None) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None, got {render_mode!r}")
        self.render_mode = render_mode
        self._renderer = None

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[NDArray[np.float32], dict[str, Any]]:
        super().reset(seed=seed)  # validates the seed, seeds np_random
        if seed is not None:
            self.task.seed_rows(np.zeros(1, dtype=np.intp), [seed])
        elif not self.task._seeded[0]:
            # Unseeded first reset: a stream from np_random (itself seeded from entropy).
            self.task.seed_rows(np.zeros(1, dtype=np.intp), [int(self.np_random.integers(2**63))])
        self.task.reset_row(0)
        if self.render_mode == "human":
            self.render()
        return self.task.obs32[0].copy(), self.task.info(0, reset=True)

    def step(self, action: Any) -> tuple[NDArray[np.float32], float, bool, bool, dict[str, Any]]:
        a = action if isinstance(action, np.ndarray) else np.asarray(action, dtype=np.float64)
        if a.shape != self.action_space.shape:
            raise ValueError(f"action must have shape {self.action_space.shape}, got {a.shape}")
        task = self.task
        if a.dtype != np.float64 and a.dtype != np.float32:
            if a.dtype.kind not in "fiub":
                raise ValueError(f"action must be real numbers, got dtype {a.dtype}")
            a = a.astype(np.float64)
        if not apply_action(a, task.force, task.action, 0, self._bound):  # task.action = clip(a): charged by the cost
            raise ValueError(f"action must be finite, got {action!r}")
        status = task.step()
        if self.render_mode == "human":
            self.render()
        return task.obs32[0].copy(), float(task.reward[0]), bool(status[0]), False, task.info(0)

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_renderer"] = None  # a pygame window does not travel
        return state

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
