"""A training run's configuration, shared by both training backends (`vnhc_gym.training.run` for
Stable-Baselines3 and SBX, `vnhc_gym.training.run_jax` for the compiled PPO and SAC): the settings, the
run's file stem, the hyperparameters it reads, and the sidecar's common fields."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import vnhc_gym
from vnhc_gym.tasks import env_id as task_env_id
from vnhc_gym.tasks import task_of_env_id
from vnhc_gym.training.hyperparams import hyperparams_dir, load_hyperparams

__all__ = ["ALGOS", "BACKENDS", "JAX_ALGOS", "SIDECAR_FORMAT", "TrainConfig", "code_fingerprint", "hyperparams_of",
           "jsonable", "resolve_env_id", "run_stem"]

#: Algorithms of ``vnhc-gym train``, each with its RL Zoo file ``agents/hyperparams/<algo>.yml``.
ALGOS = ("ppo", "residual_ppo", "recurrent_ppo", "sac", "residual_sac")
SIDECAR_FORMAT = "vnhc_gym-agent/2"
#: Training backends: Stable-Baselines3 (and SBX), or the compiled PPO and SAC (`vnhc_gym.training.ppo_jax`,
#: `sac_jax`).
BACKENDS = ("sb3", "jax")
#: The algorithms the ``"jax"`` backend trains (the residual ones on a base that is a pure function of
#: the observation: `vnhc_gym.wrappers.residual_jax.BASES`).
JAX_ALGOS = ("ppo", "residual_ppo", "sac", "residual_sac")


def default_backend(algo: str) -> str:
    """The backend of ``vnhc-gym train`` when none is named: ``"jax"`` for the algorithms it trains
    (measured faster end to end, compilation included: `experiments/bench_train.py` for PPO,
    `experiments/bench_offpolicy.py` for SAC), ``"sb3"`` for the others (recurrent PPO)."""
    return "jax" if algo in JAX_ALGOS else "sb3"


def resolve_env_id(env: str) -> str:
    """A task name (``"usv"``), an environment name (``"USVStream"``) or a full id -> the full id
    (the latest version unless the id names one)."""
    if env.startswith("vnhc_gym/") and "-v" in env:
        task_of_env_id(env)
        return env
    return task_env_id(task_of_env_id(env).name)


def code_fingerprint() -> str:
    """sha256 (first 16 hex digits) of the package's Python sources and hyperparameter files: runs
    with different fingerprints may not give the same numbers."""
    root = Path(vnhc_gym.__file__).resolve().parent
    h = hashlib.sha256()
    files = sorted(root.rglob("*.py"))
    files += sorted(hyperparams_dir().glob("*.yml"))
    for f in files:
        h.update(f.name.encode())
        h.update(f.read_bytes())
    return h.hexdigest()[:16]


@dataclass
class TrainConfig:
    """One run's configuration (also the command line of ``vnhc-gym train``)."""

    algo: str = "ppo"
    env: str = "usv"
    scenario: str = "nominal"
    seed: int = 0
    n_timesteps: int | None = None  #: default: the hyperparameter file's
    out: str = "runs"
    eval_points: int = 20  #: validation evaluations over the run (plus one at step 0)
    eval_episodes: int = 10  #: validation episodes per evaluation (seeds from VALIDATION_SEED)
    test_episodes: int = 20  #: test episodes at the end (seeds from TEST_SEED)
    threads: int = 1  #: torch threads: 1 never oversubscribes the cores (experiments/bench_train.py)
    hyperparams: str | None = None  #: another RL Zoo file for the algorithm
    overrides: dict[str, Any] = field(default_factory=dict)  #: hyperparameters that replace the file's
    #: Environment arguments of the training envs only, over the file's ``env_kwargs`` (as RL Zoo's ``--env-kwargs``)
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    progress_bar: bool = False
    residual_base: str | None = None  #: the residual's base controller (a classical baseline's name)
    residual_base_settings: dict[str, Any] | None = None  #: its settings (gain, alpha, ...)
    name: str | None = None  #: file stem (default ``<task>-<scenario>-<algo>-s<seed>``)
    #: ``"sb3"`` (Stable-Baselines3 / SBX on the native vector environment) or ``"jax"`` (PPO compiled
    #: with the environment, `vnhc_gym.training.ppo_jax`)
    backend: str = "sb3"


def run_stem(cfg: TrainConfig, env_id: str) -> str:
    """The run's file stem: ``cfg.name``, or ``<task>-<scenario>-<algo>-s<seed>``."""
    return cfg.name or f"{task_of_env_id(env_id).name}-{cfg.scenario}-{cfg.algo}-s{cfg.seed}"


def jsonable(value: Any) -> Any:
    """``value`` with every part JSON can hold kept, a class as its import path, anything else as its repr."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [jsonable(v) for v in value]
    if isinstance(value, float | int | str | bool) or value is None:
        return value
    if isinstance(value, type):
        return f"{value.__module__}.{value.__qualname__}"
    return repr(value)


def hyperparams_of(cfg: TrainConfig, env_id: str) -> tuple[dict[str, Any], TrainConfig]:
    """The run's hyperparameters (the algorithm's file, then ``cfg.overrides``) without the file's
    ``env_kwargs``, and ``cfg`` with those under its own ``env_kwargs`` (RL Zoo's rule: they shape
    the training environments only; the caller's win a clash)."""
    hp = load_hyperparams(cfg.algo, env_id, cfg.hyperparams)
    hp.update(cfg.overrides)
    file_env_kwargs = hp.pop("env_kwargs", None) or {}
    if not isinstance(file_env_kwargs, dict):
        raise ValueError(f"the hyperparameter file's env_kwargs must be a mapping, got {file_env_kwargs!r}")
    return hp, replace(cfg, env_kwargs={**file_env_kwargs, **cfg.env_kwargs})
