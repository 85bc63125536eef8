"""The single environment of any task: Gymnasium's ``reset``/``step`` around a batch of one episode.

Each task module subclasses [`ConstraintEnv`][vnhc_gym.envs.ConstraintEnv] once, with its card as the docstring and its
[`Task`][vnhc_gym.tasks.base.Task] as ``task_class``; everything else is here.
"""

from __future__ import annotations

from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

from vnhc_gym.envs.config import configure
from vnhc_gym.envs.runtime import Batch

__all__ = ["ConstraintEnv", "check_action_array"]

_ROW0 = np.zeros(1, dtype=np.intp)


def check_action_array(action: Any, shape: tuple[int, ...], name: str = "action") -> NDArray[Any]:
    """``action`` as a real array of ``shape`` (float32 or float64 kept as is), else ``ValueError``."""
    if isinstance(action, np.ndarray):
        a = action
    else:
        try:
            a = np.asarray(action, dtype=np.float64)
        except (TypeError, ValueError, OverflowError):
            raise ValueError(f"{name} must be an array of real numbers of shape {shape}, got {action!r}") from None
    if a.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {a.shape}")
    if a.dtype != np.float64 and a.dtype != np.float32:
        if a.dtype.kind not in "fiub":
            raise ValueError(f"{name} must be real numbers, got dtype {a.dtype}")
        try:
            a = a.astype(np.float64)
        except OverflowError:  # pragma: no cover - object ints are caught above
            raise ValueError(f"{name} must be finite, got {action!r}") from None
    return a


class ConstraintEnv(gym.Env[NDArray[np.float32], NDArray[np.float32]]):
    """A Gymnasium environment of one task (see the task's env card for the semantics).

    Parameters
    ----------
    scenario : str
        A name of [`vnhc_gym.envs.config.SCENARIOS`][vnhc_gym.envs.config.SCENARIOS].
    render_mode : {"rgb_array", "human"} or None
    **kwargs
        [`EnvConfig`][vnhc_gym.envs.config.EnvConfig] fields and the task's own options.
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 20}  # noqa: RUF012 (Gymnasium's API)
    task_class: ClassVar[Any]

    def __init__(self, scenario: str = "nominal", render_mode: str | None = None, **kwargs: Any) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None, got {render_mode!r}")
        self.task_class.check_definition()
        config, options = configure(scenario, kwargs, self.task_class.Options,
                                    magnitudes=self.task_class.scenario_magnitudes)
        self.scenario = scenario
        self.config = config
        self.task = self.task_class(config, options)
        self.batch = Batch(self.task, 1)
        self.render_mode = render_mode
        self._renderer: Any = None
        self.dt = config.dt  #: control period (s), as MuJoCo's envs have it
        self.action_space = spaces.Box(-1.0, 1.0, (self.task.act_dim,), np.float32)
        lim = np.float32(config.obs_clip)
        self.observation_space = spaces.Box(-lim, lim, (self.task.obs_dim,), np.float32)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[NDArray[np.float32], dict[str, Any]]:
        super().reset(seed=seed)  # validates the seed, seeds np_random
        batch = self.batch
        if seed is not None:
            batch.seed(_ROW0, [seed])
        elif not batch.seeded[0]:
            # Unseeded first reset: a stream from np_random (itself seeded from entropy).
            batch.seed(_ROW0, [int(self.np_random.integers(2**63))])
        batch.reset(_ROW0)
        if self.render_mode == "human":
            self.render()
        return batch.buf.obs32[0].copy(), batch.info(0, reset=True)

    def step(self, action: Any) -> tuple[NDArray[np.float32], float, bool, bool, dict[str, Any]]:
        a = check_action_array(action, self.action_space.shape)  # type: ignore[arg-type]
        batch = self.batch
        if batch.act(_ROW0, a.reshape(1, -1)) >= 0:
            raise ValueError(f"action must be finite, got {action!r}")
        batch.step(_ROW0)
        if self.render_mode == "human":
            self.render()
        buf = batch.buf
        return buf.obs32[0].copy(), float(buf.reward[0]), bool(buf.status[0]), False, batch.info(0)

    def render(self) -> NDArray[np.uint8] | None:
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' or 'human'.")
            return None
        return self._render_frame(0)

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        task = cls.__dict__.get("task_class")
        if task is not None and not task.draws() and cls._render_frame is ConstraintEnv._render_frame:
            cls.metadata = {**cls.metadata, "render_modes": []}  # a task with no picture renders nothing

    def _render_frame(self, row: int) -> NDArray[np.uint8] | None:
        """Render row ``row`` of the batch: the task's [`scene`][vnhc_gym.tasks.base.Task.scene], drawn
        by the planar renderer."""
        from vnhc_gym.envs.rendering import PlanarRenderer

        if self._renderer is None:
            self._renderer = PlanarRenderer(str(self.render_mode), self.metadata["render_fps"],
                                            caption=type(self).__name__)
        buf = self.batch.buf
        return self._renderer.draw(self.task.scene(buf.state[row], buf.phi[row], buf.params_true[row]))

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_renderer"] = None  # a pygame window does not travel
        return state

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

