"""``vnhc-gym tune``: hyperparameter search with Optuna, for learners and classical baselines alike,
on validation episodes only.

One study searches one algorithm in one cell (task, scenario). A trial of a learner trains it with
sampled hyperparameters (`SPACES`) for ``n_timesteps`` env steps (on Stable-Baselines3, or with
``backend="jax"`` PPO or SAC compiled with its environment), ``repeats`` times with training seeds 0, 1,
..., validating ``eval_points`` times along each run on the validation episodes (seeds from 5 000);
its value is the mean over the repeats of the best validation ``score`` (the score of the checkpoint
a run would keep). A trial of a classical baseline evaluates its sampled gains on the same
validation episodes with the same score. The test episodes (seeds from 10 000) are never run: every
learner trains with ``test_episodes=0``.

The sampler is Optuna's TPE (seeded), the pruner its median rule: a learner's trial stops when its
validation score falls below the median of the earlier trials at the same point of training.  The
study lives in an Optuna storage, a SQLite file in ``out`` by default: rerunning the same command
resumes it, and any storage URL (``--storage postgresql://...``) lets several processes or
machines share one study (start the same command on each).  Every learner gets the same budget
(``trials`` x ``repeats`` x ``n_timesteps``), so they can be compared.

Outputs in ``out/<task>-<scenario>/``: for a learner ``<algo>.yml``, the winning settings as an RL
Zoo hyperparameter file (the algorithm's shipped section with the sampled keys replaced), which
``vnhc-gym train --hyperparams`` and RL Zoo's ``--conf-file`` take; for a classical baseline
``<algo>.json``; and ``<algo>-study.json``: every trial (its parameters, value, state and seconds)
and the study's cost.
"""

from __future__ import annotations

import json
import math
import tempfile
import time
import warnings
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

__all__ = ["CLASSICAL_SPACES", "SPACES", "TuneConfig", "add_arguments", "run", "tune"]


# --------------------------------------------------------------------------- search spaces
def _ppo(trial: Any) -> dict[str, Any]:
    """PPO with the native vector env's 256 environments (rollouts of 256 x n_steps)."""
    n_steps = trial.suggest_categorical("n_steps", [16, 32, 64, 128])
    return {
        "learning_rate": trial.suggest_float("learning_rate", 1e-5, 2e-3, log=True),
        "n_steps": n_steps,
        # At most one minibatch per rollout: a larger one would only repeat the rollout.
        "batch_size": min(trial.suggest_categorical("batch_size", [1024, 2048, 4096, 8192]), 256 * n_steps),
        "n_epochs": trial.suggest_categorical("n_epochs", [3, 5, 10, 20]),
        "gamma": trial.suggest_categorical("gamma", [0.95, 0.98, 0.99, 0.995]),
        "gae_lambda": trial.suggest_categorical("gae_lambda", [0.9, 0.95, 0.98]),
        "clip_range": trial.suggest_categorical("clip_range", [0.1, 0.2, 0.3]),
        "ent_coef": trial.suggest_float("ent_coef", 1e-8, 1e-2, log=True),
        "policy_kwargs": {"log_std_init": trial.suggest_float("log_std_init", -4.0, -0.5),
                          "net_arch": [trial.suggest_categorical("width", [64, 128, 256])] * 2},
    }


def _sac(trial: Any) -> dict[str, Any]:
    """SAC with the file's 32 environments.

    The entropy target sets the policy's noise once it is met: SBX's ``"auto"`` (minus the number of
    action dimensions) leaves a noise beside which a steady miss near the constraint is small, and a
    lower target (about 55 times narrower noise at -5 on the USV's one dimension) measured a steady
    error five times smaller there (docs/training.md)."""
    target = trial.suggest_categorical("target_entropy", ["auto", "-5", "-10"])
    return {
        "target_entropy": target if target == "auto" else float(target),
        "learning_rate": trial.suggest_float("learning_rate", 1e-4, 3e-3, log=True),
        "batch_size": trial.suggest_categorical("batch_size", [128, 256, 512]),
        "gamma": trial.suggest_categorical("gamma", [0.95, 0.98, 0.99]),
        "tau": trial.suggest_categorical("tau", [0.005, 0.01, 0.02]),
        "gradient_steps": trial.suggest_categorical("gradient_steps", [2, 4, 8, 16]),
        "learning_starts": trial.suggest_categorical("learning_starts", [1000, 5000, 10000]),
        "policy_kwargs": {"net_arch": [trial.suggest_categorical("width", [64, 128, 256])] * 2},
    }


def _residual_sac(trial: Any) -> dict[str, Any]:
    params = _sac(trial)
    params["policy_kwargs"]["log_std_init"] = trial.suggest_float("log_std_init", -5.0, -2.0)
    return params


#: Learner -> its search space: a function of an Optuna trial returning hyperparameter overrides
#: (``policy_kwargs`` keys replace those of the file's ``policy_kwargs``, the others its keys).
SPACES: dict[str, Callable[[Any], dict[str, Any]]] = {
    "ppo": _ppo, "residual_ppo": _ppo, "sac": _sac, "residual_sac": _residual_sac,
}

#: Classical baseline -> its search space (log-uniform gains; the law's variant, the plain law held
#: over the control period or the sampled-data law; the observer's blend too).
CLASSICAL_SPACES: dict[str, Callable[[Any], dict[str, Any]]] = {
    "tuned_law": lambda t: {"gain": t.suggest_float("gain", 0.5, 200.0, log=True),
                            "variant": t.suggest_categorical("variant", ["plain", "sampled"])},
    "observer": lambda t: {"gain": t.suggest_float("gain", 0.5, 200.0, log=True),
                           "alpha": t.suggest_float("alpha", 1e-3, 1.0, log=True)},
    "adaptive": lambda t: {"gain": t.suggest_float("gain", 0.5, 200.0, log=True)},
}


@dataclass
class TuneConfig:
    """One study (also the command line of ``vnhc-gym tune``)."""

    algo: str = "ppo"
    env: str = "usv"
    scenario: str = "nominal"
    trials: int = 20  #: trials this call adds to the study (a resumed study keeps its earlier ones)
    n_timesteps: int = 300_000  #: env steps per training run of a learner's trial
    repeats: int = 1  #: training seeds per trial (the value is their mean)
    eval_points: int = 10  #: validations along each training run (the pruner's checkpoints)
    eval_episodes: int = 10  #: validation episodes per validation (seeds from VALIDATION_SEED)
    seed: int = 0  #: the sampler's seed
    storage: str | None = None  #: an Optuna storage URL (default: a SQLite file in ``out``)
    study: str | None = None  #: the study's name (default ``<task>-<scenario>-<algo>``)
    out: str = "tuned"
    threads: int = 1  #: torch threads per training run
    #: a learner's training backend: ``"sb3"`` or ``"jax"`` (PPO or SAC compiled with its environment)
    backend: str = "sb3"
    env_kwargs: dict[str, Any] = field(default_factory=dict)  #: the training environments' arguments only


def _check(cfg: TuneConfig) -> None:
    if cfg.algo not in (*SPACES, *CLASSICAL_SPACES):
        raise ValueError(f"algo must be one of {sorted({*SPACES, *CLASSICAL_SPACES})}, got {cfg.algo!r}")
    for name in ("trials", "n_timesteps", "repeats", "eval_points", "eval_episodes", "threads"):
        value = getattr(cfg, name)
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f"{name} must be a positive integer, got {value!r}")
    from vnhc_gym.training.config import BACKENDS, JAX_ALGOS

    if cfg.backend not in BACKENDS:
        raise ValueError(f"backend must be one of {list(BACKENDS)}, got {cfg.backend!r}")
    if cfg.backend == "jax" and cfg.algo not in JAX_ALGOS:
        raise ValueError(f"the jax backend trains {list(JAX_ALGOS)}; {cfg.algo!r} trains with backend 'sb3'")


def _merge(base: dict[str, Any], sampled: dict[str, Any]) -> dict[str, Any]:
    """The file's section with the sampled keys replaced (``policy_kwargs`` key by key)."""
    out = dict(base)
    for key, value in sampled.items():
        if key == "policy_kwargs":
            out[key] = {**(base.get(key) or {}), **value}
        else:
            out[key] = value
    return out


def _learner_objective(cfg: TuneConfig, base: dict[str, Any], work: Path) -> Callable[[Any], float]:
    import optuna

    from vnhc_gym.training.config import TrainConfig
    from vnhc_gym.training.run import train

    def objective(trial: Any) -> float:
        hp = _merge(base, SPACES[cfg.algo](trial))
        overrides = {k: v for k, v in hp.items() if k not in ("n_timesteps", "policy")}
        best: list[float] = []
        for rep in range(cfg.repeats):
            points = 0

            def report(point: dict[str, float], rep: int = rep) -> None:
                nonlocal points
                # One step per validation, counted across the repeats: every trial reports at the same steps.
                trial.report(point["score"], rep * (cfg.eval_points + 2) + points)
                points += 1
                if trial.should_prune():
                    raise optuna.TrialPruned()

            run = TrainConfig(algo=cfg.algo, env=cfg.env, scenario=cfg.scenario, seed=rep, n_timesteps=cfg.n_timesteps,
                              out=str(work), eval_points=cfg.eval_points, eval_episodes=cfg.eval_episodes,
                              test_episodes=0, threads=cfg.threads, overrides=overrides,
                              env_kwargs=dict(cfg.env_kwargs), name=f"trial{trial.number}-s{rep}",
                              backend=cfg.backend)
            meta = train(run, on_validation=report)
            best.append(max(p["score"] for p in meta["curve"]))
        return float(sum(best) / len(best))

    return objective


def _classical_objective(cfg: TuneConfig, env_id: str) -> Callable[[Any], float]:
    from vnhc_gym.baselines.tuning import evaluate_classical, selection_score
    from vnhc_gym.evaluation import VALIDATION_SEED

    def objective(trial: Any) -> float:
        settings = CLASSICAL_SPACES[cfg.algo](trial)
        res = evaluate_classical(cfg.algo, settings, env_id, cfg.scenario, cfg.eval_episodes, VALIDATION_SEED)
        return selection_score(res)

    return objective


def tune(cfg: TuneConfig | None = None, log: Callable[[str], None] | None = print, **kwargs: Any) -> dict[str, Any]:
    """Run (or resume) one study and write its winner; returns the study's summary.

    ``tune(algo="sac", env="usv", trials=20)`` works too (keyword arguments are `TuneConfig` fields).
    """
    import optuna
    import yaml

    from vnhc_gym.tasks import task_of_env_id
    from vnhc_gym.training.config import resolve_env_id
    from vnhc_gym.training.hyperparams import dump_hyperparams, load_hyperparams

    cfg = cfg or TuneConfig(**kwargs)
    _check(cfg)
    env_id = resolve_env_id(cfg.env)
    cell = f"{task_of_env_id(env_id).name}-{cfg.scenario}"
    dest = Path(cfg.out) / cell
    dest.mkdir(parents=True, exist_ok=True)
    name = cfg.study or f"{cell}-{cfg.algo}"
    url = cfg.storage or f"sqlite:///{(Path(cfg.out) / 'studies.db').resolve()}"
    learner = cfg.algo in SPACES
    # Pruning waits for a third of the first run's validations, and for five finished trials.
    pruner = optuna.pruners.MedianPruner(n_startup_trials=5, n_warmup_steps=max(1, cfg.eval_points // 3))
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    storage: Any = url
    if url.split(":", 1)[0].split("+", 1)[0] in ("sqlite", "postgresql", "mysql"):
        # A heartbeat lets a resumed study mark the trials of a killed process as failed (and not count
        # them), while trials that other live processes run on a shared storage keep running.
        with warnings.catch_warnings():  # Optuna marks heartbeats experimental: not news to the user
            warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
            storage = optuna.storages.RDBStorage(url, heartbeat_interval=60, grace_period=180)
    study = optuna.create_study(study_name=name, storage=storage, direction="maximize", load_if_exists=True,
                                sampler=optuna.samplers.TPESampler(seed=cfg.seed), pruner=pruner)
    base = load_hyperparams(cfg.algo, env_id) if learner else {}
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="vnhc-tune-") as work:
        objective = _learner_objective(cfg, base, Path(work)) if learner else _classical_objective(cfg, env_id)

        def progress(study: Any, trial: Any) -> None:
            if log is not None:
                value = "no value" if trial.value is None else f"{trial.value:.4f}"
                best = f"{study.best_value:.4f}" if _has_best(study) else "none yet"
                log(f"{name}: trial {trial.number} {trial.state.name.lower()} ({value}); best so far {best}")

        study.optimize(objective, n_trials=cfg.trials, callbacks=[progress], catch=(ValueError, RuntimeError))
    wall = time.perf_counter() - t0
    if not _has_best(study):
        raise RuntimeError(f"study {name!r} has no finished trial (every trial failed or was pruned)")
    best = study.best_trial
    trials = [{"number": t.number, "state": t.state.name, "value": t.value, "params": t.params,
               "seconds": (t.datetime_complete - t.datetime_start).total_seconds()
               if t.datetime_complete and t.datetime_start else None} for t in study.trials]
    summary = {"study": name, "storage": url, "algo": cfg.algo, "env_id": env_id, "scenario": cfg.scenario,
               "config": asdict(cfg), "best_value": best.value, "best_params": best.params,
               "n_trials": sum(t["state"] in ("COMPLETE", "PRUNED") for t in trials), "seconds_this_call": wall,
               "budget_env_steps_per_trial": cfg.repeats * cfg.n_timesteps if learner else 0, "trials": trials}
    if learner:
        # Replaying the winner's sampled parameters through the space gives its hyperparameters.
        winner = _merge(base, SPACES[cfg.algo](optuna.trial.FixedTrial(best.params)))
        # The training environments' arguments its trials had (the file's, under --env-kwargs): the file trains alike.
        env_kwargs = {**(base.get("env_kwargs") or {}), **cfg.env_kwargs}
        if env_kwargs:
            winner["env_kwargs"] = env_kwargs
        (dest / f"{cfg.algo}.yml").write_text(
            f"# vnhc-gym tune: study {name}, best validation score {best.value:.6f} over {summary['n_trials']} trials\n"
            + yaml.safe_dump({env_id: dump_hyperparams(winner)}, sort_keys=False))
        summary["file"] = str(dest / f"{cfg.algo}.yml")
    else:
        settings = CLASSICAL_SPACES[cfg.algo](optuna.trial.FixedTrial(best.params))
        (dest / f"{cfg.algo}.json").write_text(json.dumps({"settings": settings, "validation_score": best.value},
                                                          indent=1) + "\n")
        summary["file"] = str(dest / f"{cfg.algo}.json")
    (dest / f"{cfg.algo}-study.json").write_text(json.dumps(summary, indent=1, default=str) + "\n")
    if log is not None:
        log(f"{name}: best validation score {best.value:.4f} ({best.params}) -> {summary['file']}")
    return summary


def _has_best(study: Any) -> bool:
    try:
        return not math.isnan(study.best_value)
    except ValueError:  # no finished trial yet
        return False


# --------------------------------------------------------------------------- command line
def add_arguments(parser: Any) -> None:
    """The options of ``vnhc-gym tune``."""
    from vnhc_gym.envs.config import SCENARIOS

    d = TuneConfig()
    parser.add_argument("--algo", default=d.algo, choices=sorted({*SPACES, *CLASSICAL_SPACES}),
                        help=f"a learner or a classical baseline (default {d.algo})")
    parser.add_argument("--env", default=d.env, help=f"a task name or env id (default {d.env})")
    parser.add_argument("--scenario", default=d.scenario, choices=list(SCENARIOS), help=f"(default {d.scenario})")
    parser.add_argument("--trials", type=int, default=d.trials, help=f"trials to add to the study (default {d.trials})")
    parser.add_argument("-n", "--n-timesteps", type=int, default=d.n_timesteps,
                        help=f"env steps per training run (default {d.n_timesteps})")
    parser.add_argument("--repeats", type=int, default=d.repeats,
                        help=f"training seeds per trial (default {d.repeats})")
    parser.add_argument("--eval-points", type=int, default=d.eval_points, help="validations per training run")
    parser.add_argument("--eval-episodes", type=int, default=d.eval_episodes, help="validation episodes each")
    parser.add_argument("--seed", type=int, default=d.seed, help="the sampler's seed")
    parser.add_argument("--storage", default=None, help="an Optuna storage URL (default: sqlite in --out)")
    parser.add_argument("--study", default=None, help="the study's name (default <task>-<scenario>-<algo>)")
    parser.add_argument("--out", default=d.out, help=f"output folder (default {d.out})")
    parser.add_argument("--threads", type=int, default=d.threads, help="torch threads per training run")
    parser.add_argument("--backend", default=d.backend, choices=["sb3", "jax"],
                        help="a learner's training backend: sb3, or jax for PPO or SAC compiled with its environment "
                             f"(default {d.backend})")
    parser.add_argument("--env-kwargs", nargs="*", default=[], metavar="KEY:VALUE",
                        help="arguments of the training environments only (e.g. reward:reciprocal); validation "
                             "uses the environment's defaults")


def run(args: Any) -> int:
    from dataclasses import fields

    from vnhc_gym.training.cli import parse_key_values

    cfg = TuneConfig(**{f.name: getattr(args, f.name) for f in fields(TuneConfig) if f.name != "env_kwargs"},
                     env_kwargs=parse_key_values(args.env_kwargs, "--env-kwargs"))
    tune(cfg)
    return 0
