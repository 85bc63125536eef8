"""SAC's training throughput on this machine: stable-baselines3's SAC (PyTorch), SBX's (JAX), and
the SAC compiled with its environment (``vnhc-gym train --backend jax --algo sac``, one seed and five
in one program), with the settings of ``agents/hyperparams/sac.yml`` (32 environments, 8 gradient
steps every 32 transitions, batch 256, 64x64 networks), one thread each.  Writes
results/bench_offpolicy.md and .json.

    python experiments/bench_offpolicy.py            # about 6 minutes
    python experiments/bench_offpolicy.py --quick    # a smoke run

A SAC run's time is almost all gradient steps.  Each implementation runs in its own process (JAX and
PyTorch each with one thread), on the boat.  The last row is the compiled SAC's gradient steps
alone, on a buffer of random transitions with the environment left out: at the file's ratio of
environment steps to gradient steps, no implementation of this update on one thread of this machine
trains faster than that row's env-steps/s.  The figures are the steady state, after the start-up
and the compilation (reported apart for the compiled trainer): stable-baselines3 and SBX after a
warm-up, the compiled trainer over its second half (the first half holds the compilation and the
random-action phase).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

_ONE = r"""
import json, sys, time
lib, task, steps = sys.argv[1], sys.argv[2], int(sys.argv[3])
import vnhc_gym
from vnhc_gym.tasks import env_id
from vnhc_gym.training.hyperparams import load_hyperparams
if lib == "bound":
    # The compiled SAC's gradient steps alone (the environment free, the buffer full of random
    # transitions): what bounds its env-steps/s at the file's gradient steps per transition.
    import time
    import jax
    import jax.numpy as jnp
    from vnhc_gym import make_jax
    from vnhc_gym.training import sac_jax as S
    hp = load_hyperparams("sac", env_id(task))
    s = S.settings_from(hp, "sac hyperparameters")
    env, params = make_jax(env_id(task), "nominal")
    ts = jax.tree.map(lambda x: x[0], S.init(jnp.stack([jax.random.key(0)]), env, params, s))
    n, k = 10_000, jax.random.split(jax.random.key(1), 6)
    buf = S.Buffer(obs=jax.random.normal(k[0], (n, env.obs_dim)),
                   action=jax.random.uniform(k[1], (n, env.num_actions), minval=-1.0, maxval=1.0),
                   reward=jax.random.uniform(k[2], (n,)), next_obs=jax.random.normal(k[3], (n, env.obs_dim)),
                   terminated=jnp.zeros(n, bool))

    def one(ln, key):
        k_idx, k_step = jax.random.split(key)
        idx = jax.random.randint(k_idx, (s.batch_size,), 0, n)
        return S._gradient_step(s, -float(env.num_actions), ln, jax.tree.map(lambda b: b[idx], buf), k_step), None

    run = jax.jit(lambda ln, key: jax.lax.scan(one, ln, jax.random.split(key, steps))[0])
    ln = S.Learner(ts.params, ts.target, ts.opt)
    jax.block_until_ready(run(ln, k[4]))  # compilation
    t0 = time.perf_counter()
    jax.block_until_ready(run(ln, k[5]))
    wall = time.perf_counter() - t0
    per_step = hp["n_envs"] / hp["gradient_steps"]  # env steps per gradient step in the file
    print(json.dumps({"implementation": "compiled, gradient steps alone (bound)", "task": task,
                      "env_steps": steps * per_step, "wall": wall, "env_steps_per_s": steps * per_step / wall,
                      "gradient_steps_per_s": steps / wall}))
    sys.exit(0)
if lib.startswith("compiled"):
    import tempfile
    from vnhc_gym.training import TrainConfig
    from vnhc_gym.training.run_jax import train_seeds
    seeds = int(lib.split()[1])
    with tempfile.TemporaryDirectory() as d:
        meta = train_seeds(TrainConfig(algo="sac", env=task, n_timesteps=steps, eval_points=2, eval_episodes=1,
                                       test_episodes=0, backend="jax", out=d), list(range(seeds)))[0]
    c = meta["curve"]
    wall, done = c[2]["wall"] - c[1]["wall"], seeds * (c[2]["steps"] - c[1]["steps"])
    hp = load_hyperparams("sac", env_id(task))
    print(json.dumps({"implementation": f"compiled, {seeds} seed" + "s" * (seeds > 1), "task": task, "env_steps": done,
                      "wall": wall, "env_steps_per_s": done / wall,
                      "gradient_steps_per_s": done / hp["n_envs"] * hp["gradient_steps"] / wall,
                      "compile_s": meta["compile_wall"]}))
    sys.exit(0)
if lib == "stable-baselines3":
    import torch
    torch.set_num_threads(1)
    from stable_baselines3 import SAC
else:
    from vnhc_gym.training.agents import algorithm_class  # sets one XLA thread before jax loads
    SAC = algorithm_class("sac")
hp = load_hyperparams("sac", env_id(task))
n_envs = hp.pop("n_envs")
for key in ("n_timesteps", "policy"):
    hp.pop(key)
hp["learning_starts"] = 1000
venv = vnhc_gym.make_sb3_vec_env(env_id(task), n_envs=n_envs, seed=0)
model = SAC("MlpPolicy", venv, seed=0, verbose=0, device="cpu", **hp)
model.learn(hp["learning_starts"] + 20 * n_envs)  # warm-up: compilation, allocations
t0 = time.perf_counter()
model.learn(steps, reset_num_timesteps=False)
wall = time.perf_counter() - t0
grads = steps // n_envs * hp["gradient_steps"]
print(json.dumps({"implementation": lib, "task": task, "env_steps": steps, "wall": wall,
                  "env_steps_per_s": steps / wall, "gradient_steps_per_s": grads / wall}))
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer steps (CI)")
    ap.add_argument("--out", default="results/bench_offpolicy")
    args = ap.parse_args()
    rows = []
    env = {**os.environ, "XLA_FLAGS": "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"}
    for lib, steps in (("stable-baselines3", 1024 if args.quick else 32_768),
                       ("SBX", 2048 if args.quick else 131_072),
                       ("compiled 1", 32 * 64 if args.quick else 131_072),
                       ("compiled 5", 0 if args.quick else 131_072),
                       ("bound", 64 if args.quick else 4096)):
        if steps == 0:  # the smoke run leaves out the five seeds
            continue
        proc = subprocess.run([sys.executable, "-c", _ONE, lib, "usv", str(steps)], capture_output=True, text=True,
                              env=env, check=False)
        if proc.returncode != 0:
            raise RuntimeError(f"{lib} failed:\n{proc.stderr[-3000:]}")
        rows.append(json.loads(proc.stdout.strip().splitlines()[-1]))
        r = rows[-1]
        print(f"{lib:18s} {r['env_steps_per_s']:8.0f} env-steps/s  {r['gradient_steps_per_s']:6.0f} gradient steps/s",
              flush=True)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench_offpolicy.json").write_text(json.dumps(rows, indent=1))
    base = rows[0]["env_steps_per_s"]
    sbx = rows[1]["env_steps_per_s"]
    lines = ["| SAC implementation | env-steps/s | gradient steps/s | x stable-baselines3 | x SBX | 1 M env steps | "
             "compilation s |", "|---|---:|---:|---:|---:|---:|---:|"]
    lines += [f"| {r['implementation']} | {r['env_steps_per_s']:.0f} | {r['gradient_steps_per_s']:.0f} | "
              f"{r['env_steps_per_s'] / base:.1f} | {r['env_steps_per_s'] / sbx:.2f} | "
              f"{1e6 / r['env_steps_per_s'] / 60:.1f} min | {r.get('compile_s', 0.0):.0f} |" for r in rows]
    (out / "bench_offpolicy.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
