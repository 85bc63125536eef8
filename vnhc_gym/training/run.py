"""One training run: an SB3 agent on a task's native vector environment, validated while it learns
and tested on held-out episodes at the end.

``vnhc-gym train --algo ppo --env usv --scenario nominal --seed 0`` (or [`train`][vnhc_gym.training.train]) reads the
algorithm's RL Zoo file (``agents/hyperparams/<algo>.yml``), trains, and writes to ``--out``:

* ``<stem>.zip``: the SB3 model with the best validation score (the mean ``score`` of the
  validation episodes: the return over the fixed horizon per step, a failed episode's remaining
  steps counting 0, `vnhc_gym.evaluation.metrics`);
* ``<stem>-final.zip``: the model at the end of training;
* ``<stem>.json``: the sidecar, one per run: the run's configuration and hyperparameters, the package
  version and code fingerprint, the learning curve (env steps, wall time, validation scores), the
  observation statistics of both models (``obs_rms`` of the best, ``final_obs_rms`` of the final),
  and the test evaluation.  [`load_agent`][vnhc_gym.training.load_agent] loads either model with it.

``--algo`` is ``ppo`` (from scratch), ``residual_ppo`` (PPO through
[`ResidualVectorAction`][vnhc_gym.wrappers.ResidualVectorAction] on top of the geometric law; the network's last
layer starts at zero, so the untrained agent is the law), ``recurrent_ppo`` (sb3-contrib's
RecurrentPPO, an LSTM policy), ``sac`` (SBX's SAC) or ``residual_sac`` (SAC through the same
residual wrapper, its mean head zeroed and its log-std head constant at the file's
``log_std_init``).  A file's ``callback`` entries (RL Zoo's key) may name the package's own
callbacks (`vnhc_gym.training.callbacks`).  Validation episodes use seeds from 5 000, test episodes
from 10 000; training episodes use small seeds, so the three never overlap.

Threads: torch gets ``threads`` threads, 1 by default.  A second thread makes one run alone on an
idle two-core machine up to about 1.4x faster, but when another job shares the cores torch's
spinning threads fight for them: two runs started together with two threads each took 4x the time
of one run, and many times longer under heavier load, against 1.1x with one thread each
(``experiments/bench_train.py`` measures both cases).
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import Any

import vnhc_gym
from vnhc_gym.evaluation import TEST_SEED, VALIDATION_SEED, evaluate
from vnhc_gym.training.agents import AgentPolicy, algorithm_class
from vnhc_gym.training.config import (
    ALGOS,
    BACKENDS,
    SIDECAR_FORMAT,
    TrainConfig,
    code_fingerprint,
    hyperparams_of,
    jsonable,
    resolve_env_id,
    run_stem,
)
from vnhc_gym.training.hyperparams import make_schedule

__all__ = ["train"]

def _rms_json(venv: Any) -> dict[str, Any] | None:
    from stable_baselines3.common.vec_env import VecFrameStack, VecNormalize

    if isinstance(venv, VecFrameStack):
        venv = venv.venv
    if isinstance(venv, VecNormalize) and venv.norm_obs:
        rms: Any = venv.obs_rms
        return {"mean": rms.mean.tolist(), "var": rms.var.tolist(), "clip": venv.clip_obs,
                "epsilon": venv.epsilon}
    return None


def _make_env(env_id: str, cfg: TrainConfig, n_envs: int, residual: dict[str, Any] | None,
              normalize: bool | dict[str, Any], gamma: float) -> Any:
    """The training VecEnv: the native vector env, the residual wrapper if any, SB3's adapter,
    VecMonitor and VecNormalize."""
    import gymnasium as gym
    from gymnasium.vector import AutoresetMode
    from stable_baselines3.common.vec_env import VecMonitor, VecNormalize

    from vnhc_gym.sb3 import GymnasiumVecEnvAdapter
    from vnhc_gym.wrappers import ResidualVectorAction

    venv = gym.make_vec(env_id, num_envs=n_envs, vectorization_mode="vector_entry_point",
                        autoreset_mode=AutoresetMode.SAME_STEP, scenario=cfg.scenario, **cfg.env_kwargs)
    if residual is not None:
        venv = ResidualVectorAction(venv, **residual)
    sb3 = GymnasiumVecEnvAdapter(venv)
    # Training streams are seeded far from the validation and test seeds (5 000 and 10 000 up).
    sb3.seed(2**32 + cfg.seed * 2**20)
    out: Any = VecMonitor(sb3)
    if normalize:
        kwargs = dict(normalize) if isinstance(normalize, dict) else {}
        kwargs.setdefault("gamma", gamma)
        out = VecNormalize(out, **kwargs)
    return out


def _callbacks(items: list[tuple[str, dict[str, Any]]]) -> list[Any]:
    """The file's ``callback`` entries (RL Zoo's key: import paths with keyword arguments), built.
    Only the package's own callbacks are imported: a hyperparameter file names code to run."""
    import importlib

    out = []
    for path, kwargs in items:
        module, _, name = path.rpartition(".")
        if module != "vnhc_gym.training.callbacks":
            raise ValueError(f"callback {path!r} is not supported by vnhc-gym train (only vnhc_gym.training.callbacks)")
        out.append(getattr(importlib.import_module(module), name)(**kwargs))
    return out


def _start_at_base(model: Any, log_std: float | None) -> None:
    """Make the untrained residual agent exactly its base: the policy's mean action starts at zero
    (its last layer zeroed).  A SAC actor's log-std head, which depends on the observation, starts
    at the constant ``log_std`` (its weights zeroed) when the file gives ``log_std_init``: a small
    initial exploration noise around the base."""
    import torch

    if hasattr(model.policy, "action_net"):  # stable-baselines3's PPO and RecurrentPPO (torch)
        with torch.no_grad():
            head: Any = model.policy.action_net
            head.weight.zero_()
            head.bias.zero_()
        return
    import jax.numpy as jnp  # SBX's SAC: a flax actor whose last two dense layers are the mean and log-std

    state = model.policy.actor_state
    layers = dict(state.params["params"])
    dense = sorted((k for k in layers if k.startswith("Dense_")), key=lambda k: int(k.split("_")[1]))
    mean, spread = dense[-2], dense[-1]
    layers[mean] = {k: jnp.zeros_like(v) for k, v in layers[mean].items()}
    if log_std is not None:
        layers[spread] = {"kernel": jnp.zeros_like(layers[spread]["kernel"]),
                          "bias": jnp.full_like(layers[spread]["bias"], float(log_std))}
    model.policy.actor_state = state.replace(params={**state.params, "params": layers})


def _bound(agent: AgentPolicy, env_id: str, scenario: str) -> AgentPolicy:
    """``agent`` with a residual agent's base built for the scenario's environment."""
    if agent.residual is None:
        return agent
    import gymnasium as gym

    return agent.bind(gym.make(env_id, scenario=scenario))


def train(cfg: TrainConfig | None = None, log: Callable[[str], None] | None = None,
          on_validation: Callable[[dict[str, float]], None] | None = None, **kwargs: Any) -> dict[str, Any]:
    """Train one agent (see the module docstring) and return its sidecar.

    ``train(algo="ppo", env="usv", n_timesteps=200_000)`` works too (keyword arguments are
    [`TrainConfig`][vnhc_gym.training.TrainConfig] fields).  ``log`` gets one line per validation;
    ``on_validation`` gets each validation's point of the learning curve (``steps``, ``score``, ...)
    and may raise to stop the run (a hyperparameter search prunes a trial this way).  With
    ``test_episodes=0`` nothing is tested (the sidecar's ``test`` is ``None``): how a search that
    must never see the test episodes trains.  ``backend="jax"`` trains PPO or SAC compiled with their
    environment (`vnhc_gym.training.run_jax`, which also trains several seeds in one program).
    """
    cfg = cfg or TrainConfig(**kwargs)
    if cfg.algo not in ALGOS:
        raise ValueError(f"algo must be one of {list(ALGOS)}, got {cfg.algo!r}")
    if cfg.backend not in BACKENDS:
        raise ValueError(f"backend must be one of {list(BACKENDS)}, got {cfg.backend!r}")
    if isinstance(cfg.test_episodes, bool) or not isinstance(cfg.test_episodes, int) or cfg.test_episodes < 0:
        raise ValueError(f"test_episodes must be a non-negative integer, got {cfg.test_episodes!r}")
    if isinstance(cfg.threads, bool) or not isinstance(cfg.threads, int) or cfg.threads < 1:
        raise ValueError(f"threads must be a positive integer, got {cfg.threads!r}")
    env_id = resolve_env_id(cfg.env)
    if cfg.backend == "jax":
        # Imported here: the compiled trainer (and optax) load only for a run that uses it.
        from vnhc_gym.training.run_jax import train_seeds

        return train_seeds(cfg, [cfg.seed], log=log, on_validation=on_validation)[0]
    import torch

    torch.set_num_threads(cfg.threads)
    hp, cfg = hyperparams_of(cfg, env_id)
    n_envs = int(hp.pop("n_envs", 8))
    n_timesteps = int(cfg.n_timesteps if cfg.n_timesteps is not None else hp.pop("n_timesteps", 1e6))
    hp.pop("n_timesteps", None)
    policy = hp.pop("policy", "MlpPolicy")
    normalize = hp.pop("normalize", False)
    frame_stack = int(hp.pop("frame_stack", 1))
    wrappers = hp.pop("env_wrapper", [])
    callback_items = hp.pop("callback", [])
    callbacks = _callbacks(callback_items)
    residual = None
    for path, wkw in wrappers:
        if path.split(".")[-1] != "ResidualAction":
            raise ValueError(f"env_wrapper {path!r} is not supported by vnhc-gym train (only ResidualAction)")
        residual = dict(wkw)
        if cfg.residual_base is not None:
            residual["base"] = cfg.residual_base
        if cfg.residual_base_settings is not None:
            residual["base_settings"] = dict(cfg.residual_base_settings)
    for key in ("learning_rate", "clip_range"):
        if isinstance(hp.get(key), str):
            hp[key] = make_schedule(hp[key])
    gamma = float(hp.get("gamma", 0.99))
    out_dir = Path(cfg.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    stem = run_stem(cfg, env_id)
    venv = _make_env(env_id, cfg, n_envs, residual, normalize, gamma)
    if frame_stack > 1:  # the history variant: the last frame_stack observations (RL Zoo's key)
        from stable_baselines3.common.vec_env import VecFrameStack

        venv = VecFrameStack(venv, frame_stack)
    if cfg.algo == "recurrent_ppo":
        policy = "MlpLstmPolicy" if policy == "MlpPolicy" else policy
    Algo = algorithm_class(cfg.algo)
    model = Algo(policy, venv, seed=cfg.seed, device="cpu", verbose=0, **hp)
    if residual is not None:
        _start_at_base(model, (hp.get("policy_kwargs") or {}).get("log_std_init"))
    meta: dict[str, Any] = {
        "format": SIDECAR_FORMAT, "name": stem, "algo": cfg.algo, "env_id": env_id, "scenario": cfg.scenario,
        "seed": cfg.seed, "n_envs": n_envs, "n_timesteps": n_timesteps, "config": asdict(cfg),
        "hyperparams": jsonable(hp), "policy": policy, "normalize": jsonable(normalize),
        "callbacks": jsonable(callback_items),
        "residual": residual if residual is None else {**residual, "gain": residual.get("gain", 5.0)},
        "version": vnhc_gym.__version__, "code": code_fingerprint(), "obs_rms": None, "frame_stack": frame_stack,
    }
    curve: list[dict[str, float]] = []
    best = {"score": -math.inf}
    every = max(1, n_timesteps // max(1, cfg.eval_points))
    t_start = time.perf_counter()
    t_eval = 0.0

    def validate() -> None:
        nonlocal t_eval
        t0 = time.perf_counter()
        agent = _bound(AgentPolicy(model, {**meta, "obs_rms": _rms_json(venv)}), env_id, cfg.scenario)
        res = evaluate(agent, env_id, cfg.scenario, n_episodes=cfg.eval_episodes, seed=VALIDATION_SEED)
        s = res.summary(reps=200)
        point = {"steps": int(model.num_timesteps), "wall": t0 - t_start - t_eval,
                 "score": s["score"].point, "score_low": s["score"].low, "score_high": s["score"].high,
                 "success": s["success"].point,
                 "mean_abs_phi": s["mean_abs_phi"].point, "mean_abs_phi_sf": s["mean_abs_phi_sf"].point,
                 "return": s["return"].point, "terminated": s["terminated"].point}
        curve.append(point)
        if log is not None:
            log(f"{stem}: {point['steps']:>9d} steps, {point['wall']:6.0f} s: validation score {point['score']:.4f} "
                f"(success {point['success']:.2f}, IQM |phi~| {point['mean_abs_phi_sf']:.3g})")
        # Strictly better only: at a tie the earlier (for a residual agent: its base) stays.
        if point["score"] > best["score"]:
            best["score"] = point["score"]
            model.save(out_dir / f"{stem}.zip")
            meta["obs_rms"] = _rms_json(venv)
            meta["best_steps"] = point["steps"]
        t_eval += time.perf_counter() - t0
        if on_validation is not None:
            on_validation(point)

    from stable_baselines3.common.callbacks import BaseCallback

    class _Validate(BaseCallback):
        """Validates after the first rollout that crosses each multiple of ``every`` env steps (SB3
        collects whole rollouts, so at most once a rollout)."""

        def __init__(self) -> None:
            super().__init__()
            self.next = every

        def _on_step(self) -> bool:
            return True

        def _on_rollout_end(self) -> None:
            if self.num_timesteps >= self.next:
                while self.next <= self.num_timesteps:
                    self.next += every
                validate()

    try:
        validate()
        model.learn(total_timesteps=n_timesteps, callback=[_Validate(), *callbacks], progress_bar=cfg.progress_bar)
        if not curve or curve[-1]["steps"] != model.num_timesteps:
            validate()
        model.save(out_dir / f"{stem}-final.zip")
        meta["final_obs_rms"] = _rms_json(venv)
        train_wall = time.perf_counter() - t_start - t_eval
        test = None
        if cfg.test_episodes > 0:  # the test: the best validated model, on held-out seeds
            agent = _bound(AgentPolicy(Algo.load(out_dir / f"{stem}.zip", device="cpu"), meta), env_id,
                           cfg.scenario)
            result = evaluate(agent, env_id, cfg.scenario, n_episodes=cfg.test_episodes, seed=TEST_SEED)
            test = {k: v for k, v in result.to_dict().items() if k in ("metrics", "summary", "seed", "n_episodes")}
    finally:
        venv.close()
    meta.update({"curve": curve, "train_wall": train_wall, "eval_wall": t_eval,
                 "steps_per_second": model.num_timesteps / max(train_wall, 1e-9), "test": test})
    (out_dir / f"{stem}.json").write_text(json.dumps(jsonable(meta), indent=1))
    return meta

