"""Training runs on the compiled PPO and SAC (`vnhc_gym.training.ppo_jax`, `sac_jax`): several
seeds in one program, validated while they learn and tested on held-out episodes, with the files of
an SB3 run.

``vnhc-gym train --backend jax --algo ppo --env usv --seeds 0 1 2`` (or `train_seeds`) trains the
seeds side by side (``jax.vmap`` over their keys), in chunks of iterations between validations,
which come after the same iterations as an SB3 run's (`validation_iterations`).
Each seed writes what an SB3 run writes, under the same stem (``<task>-<scenario>-<algo>-s<seed>``):

* ``<stem>.npz``: the networks with the best validation score, ``<stem>-final.npz`` those at the
  end.  The arrays are named ``pi.<i>.w``, ``pi.<i>.b`` (hidden layers), ``pi_out.w``,
  ``pi_out.b``, and ``log_std`` and the value network (``vf``) for PPO, ``log_std_out.w``,
  ``log_std_out.b`` for SAC; the action is ``clip(pi_out(act(...act(obs @ pi.0.w + pi.0.b)...)),
  -1, 1)`` (PPO) or its ``tanh`` (SAC, the sidecar's ``squash``) with the sidecar's
  ``activation``.  No pickles: `load_agent` loads one from anywhere without a warning;
* ``<stem>.json``: the sidecar, as SB3 runs have it, with ``backend: "jax"``; its
  ``steps_per_second`` counts all seeds of the program and the compilation (``compile_wall``),
  ``steps_per_second_compiled`` leaves the compilation out.

Validation episodes are drawn by the functional environment with the keys
``jax.random.key(VALIDATION_SEED + i)``, in float64: the episodes a Gymnasium environment seeded
with ``VALIDATION_SEED + i`` runs, those an SB3 run validates on (`validation_scores`); the test
runs the best networks on the Gymnasium environment's test seeds with `evaluate`, exactly as for
an SB3 run, so that both backends' test scores are comparable.
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

import vnhc_gym
from vnhc_gym import make_jax, stats
from vnhc_gym.evaluation import TEST_SEED, VALIDATION_SEED, evaluate
from vnhc_gym.training import ppo_jax as P
from vnhc_gym.training import sac_jax as S
from vnhc_gym.training.agents import AgentPolicy
from vnhc_gym.training.config import (
    JAX_ALGOS,
    SIDECAR_FORMAT,
    TrainConfig,
    code_fingerprint,
    hyperparams_of,
    jsonable,
    resolve_env_id,
    run_stem,
)
from vnhc_gym.training.numpy_actor import JaxActor
from vnhc_gym.wrappers.history_jax import HistoryEnv
from vnhc_gym.wrappers.residual_jax import BASES, ResidualEnv, kalman_base, law_base

__all__ = ["train_seeds"]

#: The checkpoint's arrays, by algorithm (the sidecar's ``checkpoint_format``).
CHECKPOINT_FORMATS = {"ppo": "npz: pi.<i>.w/b, pi_out.w/b, log_std, vf.<i>.w/b, vf_out.w/b",
                      "sac": "npz: pi.<i>.w/b, pi_out.w/b, log_std_out.w/b; action tanh(pi_out)"}
CHECKPOINT_FORMATS.update({f"residual_{a}": CHECKPOINT_FORMATS[a] + "; on (obs, base action) if observe_base"
                           for a in ("ppo", "sac")})
#: The time the validation and test episodes last (s): `evaluate`'s default horizon.
EPISODE_TIME = 20.0
def validation_scores(env: Any, env_params: Any, act: Callable[[Any], Any], keys: Any, horizon: int
                      ) -> tuple[Any, Any]:
    """A deterministic policy's ``score`` (the return over ``horizon`` steps per step, the steps
    after an early end counting 0) and whether it finished, on the episodes drawn with ``keys``;
    ``act`` maps an observation to the policy's action.  Pure JAX: compiled with the run.

    Each episode's random draws follow the key chain of a Gymnasium environment seeded with the
    key's seed (`vnhc_gym.envs.runtime`: one split for the start, then one a step), so that in
    float64, with ``jax.random.key(VALIDATION_SEED + i)``, these are the episodes `evaluate`
    validates an SB3 run on."""

    def episode(key: Any) -> tuple[Any, Any]:
        key, k_reset = jax.random.split(key)
        # `initial`, not the jitted `reset`: the validation is traced in float64 and the training
        # program in float32, and a jitted method traced under both gave the float32 program a
        # float64 operand (its compilation failed).
        obs, state = env.initial(k_reset, env_params)

        def step(carry: tuple[Any, ...], _: None) -> tuple[tuple[Any, ...], None]:
            key, state, obs, total, alive = carry
            key, k = jax.random.split(key)
            new, out = env.transition(k, state, act(obs.astype(jnp.float32)), env_params)
            total = total + jnp.where(alive, out.reward, 0.0)
            return (key, new, out.obs, total, alive & ~out.terminated), None

        zero = jnp.zeros((), obs.dtype)
        (_, _, _, total, alive), _ = jax.lax.scan(step, (key, state, obs, zero, jnp.ones((), bool)), None,
                                                  length=horizon)
        return total / horizon, alive

    return jax.vmap(episode)(keys)


def validation_iterations(n_iterations: int, rollout: int, n_timesteps: int, eval_points: int) -> list[int]:
    """The iterations after which a run validates: SB3's rule (`vnhc_gym.training.run`), so that
    both backends choose their checkpoints at the same env steps.  A validation follows the first
    whole rollout that reaches each multiple of ``n_timesteps // eval_points`` env steps (at most
    one a rollout), and the run's last iteration; the start is validated as well, before these."""
    every = max(1, n_timesteps // max(1, eval_points))
    points, nxt = [], every
    for i in range(1, n_iterations + 1):
        if i * rollout >= nxt:
            while nxt <= i * rollout:
                nxt += every
            points.append(i)
    if not points or points[-1] != n_iterations:
        points.append(n_iterations)
    return points


def _save(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Written whole or not at all: a run stopped mid-write never leaves a truncated checkpoint."""
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez(tmp, **arrays)  # type: ignore[arg-type]  # numpy's stubs take the names for its own keywords
    os.replace(tmp, path)


def _residual(hp: dict[str, Any], cfg: TrainConfig, env_id: str) -> dict[str, Any]:
    """The residual settings of a ``residual_ppo`` or ``residual_sac`` run, taken out of its
    hyperparameters: the file's ``env_wrapper`` (``ResidualAction``'s ``scale`` and
    ``observe_base``), the base from ``cfg.residual_base`` (default the law) and its settings
    (``gain``, ``variant``) from ``cfg.residual_base_settings``; what the sidecar records for
    `load_agent`.  For SAC also the ``policy_kwargs``' ``log_std_init`` (``log_std_init`` in the
    result): the constant its log-standard-deviation head starts at."""
    where = f"{cfg.algo} hyperparameters of {env_id}"
    wrappers = hp.pop("env_wrapper", [])
    if len(wrappers) != 1 or wrappers[0][0].split(".")[-1] != "ResidualAction":
        raise ValueError(f"{where}: env_wrapper must be one ResidualAction, got {wrappers!r}")
    kwargs = dict(wrappers[0][1])
    unknown = sorted(set(kwargs) - {"scale", "observe_base"})
    if unknown:
        raise ValueError(f"{where}: ResidualAction's {unknown} are not implemented by the compiled backend "
                         f"(it takes scale and observe_base)")
    log_std = None
    if cfg.algo == "residual_sac":  # SBX's SAC reads log_std_init only for the residual's start (`_start_at_base`)
        pk = dict(hp.get("policy_kwargs") or {})
        log_std = pk.pop("log_std_init", None)
        hp["policy_kwargs"] = pk
    base = cfg.residual_base or "law"
    if base not in BASES:
        raise ValueError(f"backend 'jax' trains a residual on {list(BASES)}, got base {base!r} (use backend 'sb3')")
    settings = dict(cfg.residual_base_settings or {})
    known = ("gain", "variant", "q", "q_params") if base == "kalman" else ("gain", "variant")
    unknown = sorted(set(settings) - set(known))
    if unknown:
        raise ValueError(f"the base {base!r} takes {', '.join(known)}, got {unknown}")
    base_settings: dict[str, Any] = {"variant": settings.get("variant", "plain")}
    base_settings.update({k: float(settings[k]) for k in ("q", "q_params") if k in settings})
    out = {"scale": float(kwargs.get("scale", 0.2)), "observe_base": bool(kwargs.get("observe_base", False)),
           "base": base, "base_settings": base_settings, "gain": float(settings.get("gain", 5.0))}
    return out if log_std is None else {**out, "log_std_init": float(log_std)}


def _base_of(env: Any, residual: dict[str, Any], env_id: str, scenario: str, env_kwargs: dict[str, Any]) -> Any:
    """The residual's base on the functional environment ``env`` (made from ``env_id``, ``scenario``
    and ``env_kwargs``): the law, or the law on the Kalman filter of the same configured task."""
    settings = residual["base_settings"]
    if residual["base"] != "kalman":
        return law_base(env, residual["gain"], settings["variant"])
    import gymnasium as gym

    task = gym.make(env_id, scenario=scenario, **env_kwargs).unwrapped.task  # type: ignore[attr-defined]
    return kalman_base(env, task, residual["gain"], settings["variant"], q=settings.get("q", 1.0),
                       q_params=settings.get("q_params", 0.03))


def start_at_base(params: dict[str, Any], residual: dict[str, Any]) -> dict[str, Any]:
    """A residual agent's networks made exactly its base: the policy's mean head zeroed (its mean
    action is 0 for any observation) and, for SAC (``log_std_init`` in ``residual``), the
    log-standard-deviation head a constant (a small exploration noise around the base, the same
    everywhere), as `vnhc_gym.training.run` does to SB3's and SBX's networks."""
    out = {**params, "pi_out": jax.tree.map(jnp.zeros_like, params["pi_out"])}
    if "log_std_init" in residual:
        head = params["log_std_out"]
        out["log_std_out"] = {"w": jnp.zeros_like(head["w"]), "b": jnp.full_like(head["b"], residual["log_std_init"])}
    return out


def train_seeds(cfg: TrainConfig, seeds: Sequence[int], log: Callable[[str], None] | None = None,
                on_validation: Callable[[dict[str, float]], None] | None = None,
                names: Sequence[str] | None = None) -> list[dict[str, Any]]:
    """Train ``cfg`` (``algo`` one of `JAX_ALGOS`) once per seed, all seeds in one compiled
    program, and return the sidecars in the order of ``seeds``.

    ``on_validation`` gets each validation point of the first seed (as `train`'s).  Seed ``s``
    draws its networks and episodes from ``jax.random.key(s)``, so a seed gives the same run alone
    or beside others.  ``names``: each seed's file stem (default: ``cfg.name`` for one seed, else
    ``<task>-<scenario>-ppo-s<seed>``).
    """
    # One XLA thread, as one torch thread for SB3 (effective if JAX has not run anything yet): the
    # update is compute-bound and a second thread did not speed one run up (experiments/bench_train.py).
    os.environ.setdefault("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1")
    if cfg.algo not in JAX_ALGOS:
        raise ValueError(f"backend 'jax' trains {list(JAX_ALGOS)} only, got {cfg.algo!r} (use backend 'sb3')")
    seeds = [int(s) for s in seeds]
    if not seeds or len(set(seeds)) != len(seeds) or min(seeds) < 0:
        raise ValueError(f"seeds must be distinct non-negative integers, got {seeds}")
    if names is not None and (len(names) != len(seeds) or len(set(names)) != len(names)):
        raise ValueError(f"names must give each of the {len(seeds)} seeds its own stem, got {list(names)}")
    if names is None and cfg.name is not None and len(seeds) > 1:
        raise ValueError(f"name {cfg.name!r} is one file stem for {len(seeds)} seeds: pass names, one per seed")
    env_id = resolve_env_id(cfg.env)
    hp, cfg = hyperparams_of(cfg, env_id)
    if cfg.n_timesteps is not None:
        hp["n_timesteps"] = int(cfg.n_timesteps)
    residual = _residual(hp, cfg, env_id) if cfg.algo.startswith("residual_") else None
    frame_stack = int(hp.pop("frame_stack", 1))  # the history variant (RL Zoo's key; SB3's VecFrameStack)
    if frame_stack > 1 and (residual is not None or cfg.algo != "ppo"):
        raise ValueError(f"{cfg.algo} hyperparameters of {env_id}: the compiled backend stacks frames for PPO from "
                         f"scratch only (frame_stack {frame_stack})")
    sac = cfg.algo in ("sac", "residual_sac")
    algo = S if sac else P
    settings = algo.settings_from(hp, f"{cfg.algo} hyperparameters of {env_id}")
    activation, squash = ("ReLU", "tanh") if sac else (settings.activation, "clip")
    env, env_params = make_jax(env_id, cfg.scenario, **cfg.env_kwargs)
    val_env, val_params = make_jax(env_id, cfg.scenario)
    if residual is not None:  # the same base, with its settings, on the training and validation episodes
        env = ResidualEnv.around(env, _base_of(env, residual, env_id, cfg.scenario, cfg.env_kwargs),
                                 residual["scale"], residual["observe_base"])
        val_env = ResidualEnv.around(val_env, _base_of(val_env, residual, env_id, cfg.scenario, {}),
                                     residual["scale"], residual["observe_base"])
    if frame_stack > 1:
        env, val_env = HistoryEnv.around(env, frame_stack), HistoryEnv.around(val_env, frame_stack)
    horizon = max(1, round(EPISODE_TIME / float(val_params.dt)))
    val_keys = jnp.stack([jax.random.key(VALIDATION_SEED + i) for i in range(cfg.eval_episodes)])
    points = validation_iterations(settings.n_iterations, settings.rollout, settings.n_timesteps, cfg.eval_points)
    chunk = max(b - a for a, b in zip([0, *points], points, strict=False))  # one program: the longest stretch
    out_dir = Path(cfg.out)
    out_dir.mkdir(parents=True, exist_ok=True)

    run_chunk = jax.jit(jax.vmap(lambda ts, until: algo.iterations(env, env_params, settings, ts, chunk, until),
                                 in_axes=(0, None)))
    if not sac:
        def act(p: Any, obs: Any) -> Any:  # the Gaussian's mean, clipped to the action box as SB3 clips
            return jnp.clip(P.actor_apply(p, obs, activation), -1.0, 1.0)
    else:
        def act(p: Any, obs: Any) -> Any:  # the squashed Gaussian's mean
            return jnp.tanh(S.actor_apply(p, obs)[0])
    validate_x64 = jax.jit(jax.vmap(lambda p: validation_scores(val_env, val_params, lambda o: act(p, o), val_keys,
                                                                horizon)))

    def validate(params: Any) -> Any:
        # In float64, the Gymnasium environment's precision: its random draws are then the same, and
        # these are the episodes an SB3 run validates on (the networks still act in float32).
        with jax.enable_x64(True):
            return validate_x64(params)

    stems = list(names) if names is not None else [run_stem(replace(cfg, seed=s), env_id) for s in seeds]
    metas = [{"format": SIDECAR_FORMAT, "backend": "jax", "name": stem, "algo": cfg.algo, "env_id": env_id,
              "scenario": cfg.scenario, "seed": s, "n_envs": settings.n_envs, "n_timesteps": settings.n_timesteps,
              "config": {**asdict(cfg), "seed": s}, "hyperparams": jsonable(hp), "policy": "MlpPolicy",
              "activation": activation, "squash": squash, "normalize": jsonable(hp.get("normalize", False)),
              "residual": residual, "version": vnhc_gym.__version__, "code": code_fingerprint(), "obs_rms": None,
              "frame_stack": frame_stack, "checkpoint_format": CHECKPOINT_FORMATS[cfg.algo]}
             for s, stem in zip(seeds, stems, strict=True)]
    curves: list[list[dict[str, float]]] = [[] for _ in seeds]
    best = [-math.inf] * len(seeds)
    t_start = time.perf_counter()
    t_eval = 0.0

    def check(ts: Any) -> None:
        nonlocal t_eval
        t0 = time.perf_counter()
        scores, alive = (np.asarray(x, dtype=np.float64) for x in validate(ts.params))
        steps = int(np.asarray(ts.iteration)[0]) * settings.rollout
        params = jax.device_get(ts.params)
        for i, meta in enumerate(metas):
            # The interval SB3's runs record too (`EvalResult.summary`): a residual agent's parity
            # is its lower end clearing its base's score.
            iv = stats.interval_estimates({"x": scores[i][None, :]}, metric="mean", reps=200)["x"]
            point = {"steps": steps, "wall": t0 - t_start - t_eval, "score": float(scores[i].mean()),
                     "score_low": iv.low, "score_high": iv.high, "success": float(alive[i].mean())}
            curves[i].append(point)
            if log is not None:
                log(f"{meta['name']}: {steps:>9d} steps, {point['wall']:6.0f} s: validation score "
                    f"{point['score']:.4f} (success {point['success']:.2f})")
            if point["score"] > best[i]:  # strictly better only: at a tie the earlier stays
                best[i] = point["score"]
                _save(out_dir / f"{meta['name']}.npz", algo.to_numpy(jax.tree.map(lambda x, i=i: x[i], params)))
                meta["best_steps"] = steps
        t_eval += time.perf_counter() - t0
        if on_validation is not None:
            on_validation(curves[0][-1])

    ts = algo.init(jnp.stack([jax.random.key(s) for s in seeds]), env, env_params, settings)
    if residual is not None:
        ts = ts._replace(params=start_at_base(ts.params, residual))
    check(ts)
    t0 = time.perf_counter()
    step_chunk = run_chunk.lower(ts, jnp.int32(0)).compile()
    compile_wall = time.perf_counter() - t0
    for until in points:
        ts, _ = step_chunk(ts, jnp.int32(until))
        jax.block_until_ready(ts)  # else the chunk's time would be counted in the validation's
        check(ts)
    train_wall = time.perf_counter() - t_start - t_eval
    params = jax.device_get(ts.params)
    for i, meta in enumerate(metas):
        _save(out_dir / f"{meta['name']}-final.npz", algo.to_numpy(jax.tree.map(lambda x, i=i: x[i], params)))
        test = None
        if cfg.test_episodes > 0:  # the test: the best validated networks, on the held-out seeds
            agent = AgentPolicy(JaxActor.load(out_dir / f"{meta['name']}.npz", activation, squash), meta)
            if residual is not None:  # its base, built for the test's environment
                import gymnasium as gym

                agent.bind(gym.make(env_id, scenario=cfg.scenario))
            result = evaluate(agent, env_id, cfg.scenario, n_episodes=cfg.test_episodes, seed=TEST_SEED)
            test = {k: v for k, v in result.to_dict().items() if k in ("metrics", "summary", "seed", "n_episodes")}
        steps = int(np.asarray(ts.iteration)[i]) * settings.rollout
        meta.update({"curve": curves[i], "train_wall": train_wall, "compile_wall": compile_wall, "eval_wall": t_eval,
                     "seeds_in_program": len(seeds), "steps_per_second": len(seeds) * steps / max(train_wall, 1e-9),
                     "steps_per_second_compiled": len(seeds) * steps / max(train_wall - compile_wall, 1e-9),
                     "test": test})
        (out_dir / f"{meta['name']}.json").write_text(json.dumps(jsonable(meta), indent=1))
    return metas
