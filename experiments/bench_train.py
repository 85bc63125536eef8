"""PPO training throughput: the two backends side by side on every task (Stable-Baselines3 on the
native vector environment, and PPO compiled with its environment, one seed and five in one
program), where a compiled iteration spends its time (the environment, the update) and what that
bounds, then SB3's env-steps per second at several batch sizes, with the rollout (environment +
policy inference) and update (gradient steps) shares, and the effect of torch's thread count, alone
and with two trainings at once.  Writes results/bench_train.md and .json.

    python experiments/bench_train.py              # about 20 minutes on 2 cores
    python experiments/bench_train.py --backends   # the side-by-side table only (13 minutes)
    python experiments/bench_train.py --split      # where a compiled iteration spends its time (a minute a task)
    python experiments/bench_train.py --quick      # a smoke run

Both backends train with the same settings (agents/hyperparams/ppo.yml: 256 environments x 64
steps, minibatches of 4096, 5 epochs, 64x64 tanh networks) through ``vnhc_gym.training.train``, so
each figure is the user's job: env steps over the training wall time (SB3's start-up and the
compiled program's compilation included; the validations excluded, as they are for both).  On a
GPU the same command prints the GPU's figures for the compiled backend.

At 256 environments the run compares one torch thread with two.  The
concurrent case is the user's whole job: ``vnhc-gym train`` processes (start-up, training,
validation and test included), one alone and two started together, with one torch thread each
(the default) and with two (the oversubscribed case: four spinning threads on two cores); each
finds its compiled programs in one JAX compilation cache, warmed first by a run that is not timed.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import torch
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback

import vnhc_gym
from vnhc_gym.tasks import TASKS, env_id


class _Clock(BaseCallback):
    """Time spent collecting rollouts (the rest of learn() is the update)."""

    def __init__(self) -> None:
        super().__init__()
        self.rollout = 0.0
        self._t = 0.0

    def _on_rollout_start(self) -> None:
        self._t = time.perf_counter()

    def _on_rollout_end(self) -> None:
        self.rollout += time.perf_counter() - self._t

    def _on_step(self) -> bool:
        return True


def measure(task: str, n_envs: int, threads: int, steps: int) -> dict[str, float]:
    torch.set_num_threads(threads)
    venv = vnhc_gym.make_sb3_vec_env(env_id(task), n_envs=n_envs, seed=0)
    n_steps = max(16, 16384 // n_envs)
    model = PPO("MlpPolicy", venv, n_steps=n_steps, batch_size=min(4096, n_envs * n_steps), n_epochs=5, seed=0,
                device="cpu", policy_kwargs={"net_arch": [64, 64]})
    model.learn(n_envs * n_steps)  # warm-up: compilation, allocations
    clock = _Clock()
    t0 = time.perf_counter()
    model.learn(steps, callback=clock, reset_num_timesteps=True)
    wall = time.perf_counter() - t0
    venv.close()
    done = model.num_timesteps
    return {"task": task, "n_envs": n_envs, "threads": threads, "steps": done, "wall": wall,
            "steps_per_s": done / wall, "rollout_share": clock.rollout / wall}


def backends(task: str, steps: int, seeds: tuple[int, ...]) -> list[dict[str, float]]:
    """One task: SB3's PPO, and the compiled PPO with each number of ``seeds`` in one program."""
    from vnhc_gym.training import TrainConfig, train
    from vnhc_gym.training.run_jax import train_seeds

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        common = {"algo": "ppo", "env": task, "n_timesteps": steps, "eval_points": 1, "eval_episodes": 5,
                  "test_episodes": 0}
        meta = train(TrainConfig(**common, out=str(Path(tmp) / "sb3")))
        rows.append({"task": task, "backend": "sb3", "seeds": 1, "steps_per_s": meta["steps_per_second"],
                     "compile_s": 0.0, "steps_per_s_compiled": meta["steps_per_second"]})
        for n in seeds:
            meta = train_seeds(TrainConfig(**common, backend="jax", out=str(Path(tmp) / f"jax{n}")), list(range(n)))[0]
            rows.append({"task": task, "backend": "jax", "seeds": n, "steps_per_s": meta["steps_per_second"],
                         "compile_s": meta["compile_wall"], "steps_per_s_compiled": meta["steps_per_second_compiled"]})
    return rows


def split(task: str, chunk: int = 10) -> dict[str, float]:
    """Where a compiled PPO iteration of one seed spends its time: ``chunk`` iterations of the whole
    program (rollout, advantages, updates) against the same number of environment steps alone (the
    same batch, uniform random actions, no policy), each timed after its compilation; and the
    compilation of the training program.  The update's time per env step bounds what any speed-up
    of the environment can give: with the environment free, a run of ``n`` steps takes at least
    ``n * update + compilation``."""
    # One XLA thread, as the compiled trainer runs (effective before JAX's first computation).
    os.environ.setdefault("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1")
    import jax
    import jax.numpy as jnp

    from vnhc_gym import make_jax
    from vnhc_gym.training import ppo_jax as P
    from vnhc_gym.training.hyperparams import load_hyperparams

    eid = env_id(task)
    s = P.settings_from(load_hyperparams("ppo", eid), f"ppo hyperparameters of {eid}")
    env, params = make_jax(eid, "nominal")
    ts = P.init(jnp.stack([jax.random.key(0)]), env, params, s)
    run = jax.jit(jax.vmap(lambda t: P.iterations(env, params, s, t, chunk)))
    t0 = time.perf_counter()
    compiled = run.lower(ts).compile()
    compile_s = time.perf_counter() - t0
    ts = jax.block_until_ready(compiled(ts))[0]  # a warm-up pass
    t0 = time.perf_counter()
    jax.block_until_ready(compiled(ts))
    whole = time.perf_counter() - t0

    def rollout(state: Any, obs: Any, key: Any) -> Any:
        def step(carry: Any, k: Any) -> Any:
            st, _ = carry
            k_act, k_env = jax.random.split(k)
            a = jax.random.uniform(k_act, (s.n_envs, env.num_actions), minval=-1.0, maxval=1.0)
            o2, st2, r, *_ = env.step_batch(k_env, st, a, params)
            return (st2, o2), r
        return jax.lax.scan(step, (state, obs), jax.random.split(key, s.n_steps * chunk))[1]

    alone = jax.jit(rollout)
    first = (jax.tree.map(lambda x: x[0], ts.env), ts.obs[0])
    jax.block_until_ready(alone(*first, jax.random.key(1)))
    t0 = time.perf_counter()
    jax.block_until_ready(alone(*first, jax.random.key(2)))
    env_s = time.perf_counter() - t0
    steps = chunk * s.rollout
    return {"task": task, "steps": steps, "iteration_us_per_step": 1e6 * whole / steps,
            "env_us_per_step": 1e6 * env_s / steps, "update_us_per_step": 1e6 * (whole - env_s) / steps,
            "compile_s": compile_s}


def split_table(tasks: tuple[str, ...], out: Path) -> str:
    """`split` on each task, written to ``out/bench_split.md`` and ``.json``; returns the table."""
    parts = [split(task) for task in tasks]
    lines = ["| task | whole iteration us/step | environment alone us/step | update us/step | update share | "
             "compilation s | k env-steps/s at most, free environment, 983 040 steps |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    for r in parts:
        update = r["update_us_per_step"]
        bound = 983_040 / (983_040 * update * 1e-6 + r["compile_s"])
        lines.append(f"| {r['task']} | {r['iteration_us_per_step']:.2f} | {r['env_us_per_step']:.2f} | {update:.2f} | "
                     f"{100 * update / r['iteration_us_per_step']:.0f} % | {r['compile_s']:.1f} | {bound / 1e3:.1f} |")
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench_split.json").write_text(json.dumps(parts, indent=1))
    table = "\n".join(lines) + "\n"
    (out / "bench_split.md").write_text(table)
    return table


def concurrent(jobs: int, threads: int, steps: int, task: str = "usv") -> dict[str, float]:
    """Wall time of ``jobs`` ``vnhc-gym train`` processes started together (``threads`` torch threads each)."""
    exe = shutil.which("vnhc-gym")
    cmd = [exe] if exe else [sys.executable, "-c", "import sys; from vnhc_gym.cli import main; sys.exit(main())"]
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        procs = [subprocess.Popen([*cmd, "train", "--algo", "ppo", "--env", task, "-n", str(steps), "--seed", str(i),
                                   "--threads", str(threads), "--out", str(Path(tmp) / str(i))],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True) for i in range(jobs)]
        for p in procs:
            _, err = p.communicate()
            if p.returncode != 0:
                raise RuntimeError(f"vnhc-gym train failed:\n{err}")
        wall = time.perf_counter() - t0
    return {"task": task, "jobs": jobs, "threads": threads, "steps": steps, "wall": wall}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer steps and sizes (CI)")
    ap.add_argument("--backends", action="store_true", help="the side-by-side table of the backends only")
    ap.add_argument("--split", action="store_true",
                    help="only where a compiled PPO iteration spends its time (environment, update), every task")
    ap.add_argument("--out", default="results/bench_train")
    args = ap.parse_args()
    if args.split:
        print(split_table(("usv",) if args.quick else tuple(TASKS), Path(args.out)))
        return
    side = []
    for task in (("usv",) if args.quick else TASKS):
        # The smoke run compiles one training program (two seeds): the programs' compilation is
        # most of its time.
        side += backends(task, 16_384 if args.quick else 983_040, (2,) if args.quick else (1, 5))
        for r in side[-(2 if args.quick else 3):]:
            print(f"{task:10s} {r['backend']:4s} seeds={r['seeds']}  {r['steps_per_s'] / 1e3:7.1f} k env-steps/s "
                  f"(compilation {r['compile_s']:4.1f} s; without it {r['steps_per_s_compiled'] / 1e3:7.1f} k)",
                  flush=True)
    table = ["| task | backend | seeds in one program | k env-steps/s | x SB3 | compilation s | k env-steps/s "
             "without compilation |", "|---|---|---:|---:|---:|---:|---:|"]
    sb3 = {r["task"]: r["steps_per_s"] for r in side if r["backend"] == "sb3"}
    table += [f"| {r['task']} | {r['backend']} | {r['seeds']} | {r['steps_per_s'] / 1e3:.1f} | "
              f"{r['steps_per_s'] / sb3[r['task']]:.2f} | {r['compile_s']:.1f} | "
              f"{r['steps_per_s_compiled'] / 1e3:.1f} |"
              for r in side]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench_backends.json").write_text(json.dumps(side, indent=1))
    (out / "bench_backends.md").write_text("\n".join(table) + "\n")
    if args.backends:
        print("\n".join(table))
        return
    print(split_table(("usv",) if args.quick else tuple(TASKS), out), flush=True)
    steps = 8192 if args.quick else 196_608
    sizes = [8] if args.quick else [8, 64, 256, 1024]
    rows = []
    for task in (("usv",) if args.quick else ("flocking", "usv")):
        for n in sizes:
            for threads in ([1] if n != 256 or args.quick else [1, 2]):
                rows.append(measure(task, n, threads, steps))
                r = rows[-1]
                print(f"{task:9s} n_envs={n:5d} threads={threads}  {r['steps_per_s'] / 1e3:7.1f} k env-steps/s  "
                      f"rollout {100 * r['rollout_share']:4.1f} %  update {100 * (1 - r['rollout_share']):4.1f} %",
                      flush=True)
    # Every process finds the programs in one compilation cache, warmed by a run that is not timed (as
    # the command's second and later runs do): else the first timed run alone pays the compilation.
    # The smoke run leaves the whole processes out: three more start-ups for timings that mean nothing
    # at its budget (the command itself is tested on its own).
    together = []
    with tempfile.TemporaryDirectory(prefix="bench_train_jax_cache_") as cache:
        os.environ["VNHC_GYM_JAX_CACHE"] = cache
        if not args.quick:
            concurrent(1, 1, 16_384)
        for threads in (() if args.quick else (1, 2)):
            for jobs in (1, 2):
                together.append(concurrent(jobs, threads, 300_000))
                r = together[-1]
                print(f"{jobs} x vnhc-gym train, {threads} torch thread(s) each: {r['wall']:6.1f} s", flush=True)
    (out / "bench_train.json").write_text(json.dumps({"backends": side, "throughput": rows, "concurrent": together},
                                                     indent=1))
    lines = [*table, "", "| task | n_envs | torch threads | k env-steps/s | rollout share | update share |",
             "|---|---:|---:|---:|---:|---:|"]
    lines += [f"| {r['task']} | {r['n_envs']} | {r['threads']} | {r['steps_per_s'] / 1e3:.1f} | "
              f"{100 * r['rollout_share']:.0f} % | {100 * (1 - r['rollout_share']):.0f} % |" for r in rows]
    if together:
        solo = {r["threads"]: r["wall"] for r in together if r["jobs"] == 1}
        lines += ["", f"`vnhc-gym train --algo ppo --env {together[0]['task']} -n {together[0]['steps']}`, whole "
                  "processes (start-up, training, validation, test):", "",
                  "| runs started together | torch threads each | wall s | x one run alone (1 thread) |",
                  "|---:|---:|---:|---:|"]
        lines += [f"| {r['jobs']} | {r['threads']} | {r['wall']:.1f} | {r['wall'] / solo[1]:.2f} |" for r in together]
    (out / "bench_train.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
