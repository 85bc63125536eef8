"""The task registry: every environment, baseline, training run and benchmark reads its tasks here.

Each entry names a task module (one file: its hooks, its [`Task`][vnhc_gym.tasks.base.Task] and its
environment class with the card) and the environment's name; the registry makes the native vector
version ([`vector_env_class`][vnhc_gym.envs.vector.vector_env_class]).
Importing `vnhc_gym` registers ``vnhc_gym/<EnvName>-v0`` and ``-v1`` for each entry with
Gymnasium, without importing the task modules (they load when an environment is made).
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from types import ModuleType
from typing import TYPE_CHECKING, Any

from gymnasium.envs.registration import register, registry

if TYPE_CHECKING:
    from vnhc_gym.envs.functional import EnvParams, FunctionalEnv

__all__ = ["TASKS", "Task", "TaskEntry", "VERSIONS", "env_id", "env_ids", "get_task", "make_jax",
           "register_task", "shipped_tasks", "task_of_env_id"]


def __getattr__(name: str) -> Any:  # Task imports JAX: only when a task author asks for it
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

    @property
    def shipped(self) -> bool:
        """True for the package's own tasks (their module is in `vnhc_gym`), False for a user's."""
        return self.module.startswith("vnhc_gym.")

    def load(self) -> ModuleType:
        """The task module (imported on first use)."""
        return importlib.import_module(self.module)

    @property
    def env_class(self) -> Any:
        """The single environment class (``<env_name>Env`` of the module)."""
        return self.load().__dict__[f"{self.env_name}Env"]

    @property
    def vector_class(self) -> Any:
        """The native vector environment class (the module's, or made from the single one)."""
        from vnhc_gym.envs.vector import vector_env_class

        return vector_env_class(self.env_class)

    @property
    def task_class(self) -> Any:
        return self.env_class.task_class


@dataclass(frozen=True)
class VectorEntryPoint:
    """Gymnasium's ``vector_entry_point`` of a task: builds the native vector env on first use
    (a picklable callable, so registering imports nothing)."""

    module: str
    env_name: str

    def __call__(self, **kwargs: Any) -> Any:
        return TaskEntry(self.env_name, self.env_name, self.module).vector_class(**kwargs)


TASKS: dict[str, TaskEntry] = {}


def register_task(name: str, env_name: str, module: str, max_episode_steps: int = 400) -> TaskEntry:
    """Add a task to the registry and register its environments with Gymnasium.

    ``module`` must define ``<env_name>Env`` (its vector version is made here); the ids are
    ``vnhc_gym/<env_name>-v0`` and ``-v1`` (``VERSIONS``).
    """
    entry = TaskEntry(name, env_name, module)
    TASKS[name] = entry
    for version, kwargs in entry.versions.items():
        env = f"vnhc_gym/{env_name}-{version}"
        if env not in registry:
            register(id=env, entry_point=f"{module}:{env_name}Env",
                     vector_entry_point=VectorEntryPoint(module, env_name),
                     max_episode_steps=max_episode_steps, kwargs=dict(kwargs))
    return entry


def shipped_tasks() -> dict[str, TaskEntry]:
    """The package's own registered tasks (those with tuned settings, shipped agents and results)."""
    return {name: e for name, e in TASKS.items() if e.shipped}


def env_id(task: str, version: str = LATEST) -> str:
    """The Gymnasium id of a task's environment, e.g. ``env_id("usv") == "vnhc_gym/USVStream-v1"``."""
    return f"vnhc_gym/{get_entry(task).env_name}-{version}"


def env_ids(version: str | None = LATEST, *, shipped_only: bool = False) -> list[str]:
    """Every registered environment id (of one version, or of all with ``version=None``; only the
    package's own tasks with ``shipped_only``)."""
    versions = [version] if version is not None else list(VERSIONS)
    return [f"vnhc_gym/{e.env_name}-{v}" for e in TASKS.values() if e.shipped or not shipped_only for v in versions]


def get_entry(task: str) -> TaskEntry:
    if task not in TASKS:
        raise ValueError(f"unknown task {task!r}; registered: {sorted(TASKS)}")
    return TASKS[task]


def get_task(task: str) -> Any:
    """The [`Task`][vnhc_gym.tasks.base.Task] subclass of a registered task."""
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
register_task("cartpole", "CartPoleBalance", "vnhc_gym.tasks.cartpole")
register_task("spacecraft", "SpacecraftPoint", "vnhc_gym.tasks.spacecraft")


def make_jax(env_id: str, scenario: str = "nominal", *, feedback: str = "open", gains: Any = 1.0,
             max_steps: int = 400, **kwargs: Any) -> tuple[FunctionalEnv, EnvParams]:
    """A registered environment as pure JAX functions with gymnax's interface, and its parameters.

    The same keyword arguments as ``gym.make(env_id, scenario=..., **kwargs)`` (checked the same
    way), as in ``gymnax.make``::

        env, params = make_jax("vnhc_gym/USVStream-v1", scenario="noisy")
        obs, state = env.reset(jax.random.key(0), params)
        obs, state, reward, terminated, truncated, info = env.step(key, state, action, params)

    Parameters
    ----------
    env_id : str
        ``"vnhc_gym/USVStream-v1"`` (the version's defaults apply: ``-v0``'s raw reward), or a task name.
    scenario : str
    feedback, gains : see `FunctionalEnv` (the law inside the integrator)
    max_steps : int
        The time limit of the automatic reset (the registry's 400 steps).
    """
    # Here, not at the top: the registry is imported with `vnhc_gym`, and JAX only when an
    # environment is made.
    from vnhc_gym.envs.config import configure

    entry = task_of_env_id(env_id)
    version = env_id.rsplit("-", 1)[-1] if "-v" in env_id else "v1"
    task_class = entry.task_class
    task_class.check_definition()
    config, options = configure(scenario, {**VERSIONS.get(version, {}), **kwargs}, task_class.Options,
                                magnitudes=task_class.scenario_magnitudes)
    return task_class(config, options).functional(feedback=feedback, gains=gains, max_steps=max_steps)
