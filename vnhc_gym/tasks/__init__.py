"""The task registry: every environment, baseline, training run and benchmark reads its tasks here.

Each entry names a task module (one file: its hooks, its :class:`~vnhc_gym.tasks.base.Task`, its
environment class with the card and the native vector version) and the environment's name.
Importing :mod:`vnhc_gym` registers ``vnhc_gym/<EnvName>-v0`` and ``-v1`` for each entry with
Gymnasium, without importing the task modules (they load when an environment is made).
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from types import ModuleType
from typing import Any

from gymnasium.envs.registration import register, registry

__all__ = ["TASKS", "Task", "TaskEntry", "VERSIONS", "env_id", "env_ids", "get_task", "register_task",
           "task_of_env_id"]


def __getattr__(name: str) -> Any:  # Task imports numba: only when a task author asks for it
    if name == "Task":
        from vnhc_gym.tasks.base import Task

        return Task
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

#: Keyword arguments each version adds to the environment's (latest) defaults: ``-v0`` restores the
#: raw ``-|phi|`` reward of the original benchmark.
VERSIONS: dict[str, dict[str, Any]] = {"v0": {"reward": "raw"}, "v1": {}}
#: The version the docs, the defaults and the comparison use.
LATEST = "v1"


@dataclass(frozen=True)
class TaskEntry:
    """A registered task: its name, its environment's name and the module that defines both."""

    name: str
    env_name: str
    module: str
    versions: dict[str, dict[str, Any]] = field(default_factory=lambda: dict(VERSIONS))

    def load(self) -> ModuleType:
        """The task module (imported on first use)."""
        return importlib.import_module(self.module)

    @property
    def task_class(self) -> Any:
        return self.load().__dict__[f"{self.env_name}Env"].task_class


TASKS: dict[str, TaskEntry] = {}


def register_task(name: str, env_name: str, module: str, max_episode_steps: int = 400) -> TaskEntry:
    """Add a task to the registry and register its environments with Gymnasium.

    ``module`` must define ``<env_name>Env`` and ``<env_name>VectorEnv``; the ids are
    ``vnhc_gym/<env_name>-v0`` and ``-v1`` (``VERSIONS``).
    """
    entry = TaskEntry(name, env_name, module)
    TASKS[name] = entry
    for version, kwargs in entry.versions.items():
        env = f"vnhc_gym/{env_name}-{version}"
        if env not in registry:
            register(id=env, entry_point=f"{module}:{env_name}Env", vector_entry_point=f"{module}:{env_name}VectorEnv",
                     max_episode_steps=max_episode_steps, kwargs=dict(kwargs))
    return entry


def env_id(task: str, version: str = LATEST) -> str:
    """The Gymnasium id of a task's environment, e.g. ``env_id("usv") == "vnhc_gym/USVStream-v1"``."""
    return f"vnhc_gym/{get_entry(task).env_name}-{version}"


def env_ids(version: str | None = LATEST) -> list[str]:
    """Every registered environment id (of one version, or of all with ``version=None``)."""
    versions = [version] if version is not None else list(VERSIONS)
    return [f"vnhc_gym/{e.env_name}-{v}" for e in TASKS.values() for v in versions]


def get_entry(task: str) -> TaskEntry:
    if task not in TASKS:
        raise ValueError(f"unknown task {task!r}; registered: {sorted(TASKS)}")
    return TASKS[task]


def get_task(task: str) -> Any:
    """The :class:`~vnhc_gym.tasks.base.Task` subclass of a registered task."""
    return get_entry(task).task_class


def task_of_env_id(env: str) -> TaskEntry:
    """The registry entry of an environment id such as ``"vnhc_gym/USVStream-v1"`` (or a short name
    such as ``"usv"`` or ``"USVStream"``)."""
    for entry in TASKS.values():
        if env in (entry.name, entry.env_name) or env.removeprefix("vnhc_gym/").split("-v")[0] == entry.env_name:
            return entry
    raise ValueError(f"unknown environment {env!r}; registered: {env_ids(None)} (or the task names {sorted(TASKS)})")


register_task("flocking", "FlockingAlign", "vnhc_gym.tasks.flocking")
register_task("usv", "USVStream", "vnhc_gym.tasks.usv")
register_task("sled", "SledCruise", "vnhc_gym.tasks.sled")
