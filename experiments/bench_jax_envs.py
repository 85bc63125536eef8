"""Throughput of the environments as pure JAX functions (`vnhc_gym.make_jax`),
beside the native vector environments, on every task.  Writes results/bench_jax_envs.md and .json.

    python experiments/bench_jax_envs.py            # a few minutes
    python experiments/bench_jax_envs.py --quick    # a smoke run

Two ways to drive the same jitted, vmapped step (gymnax's, with its automatic reset):

- ``scan``: many steps inside one compiled program (``jax.lax.scan``), as a learner that keeps the
  environment inside its compiled update does;
- ``loop``: one compiled call per step from Python, numpy actions in and, out to numpy, everything
  the native vector environment's step returns (observations, rewards, flags and the info arrays),
  with the episodes' memory and the key kept on JAX's side: the least a Gymnasium vector
  environment that calls the compiled step once per step can pay.

Uniform random actions, episodes of 400 steps with resets; float32 (JAX's default) and float64
(inside ``jax.enable_x64``).  The native vector environment's figure is measured in the same run.
Compile time is reported apart and not counted.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np

import vnhc_gym  # noqa: F401
from vnhc_gym import make_jax
from vnhc_gym.tasks import env_ids


def jax_rates(env_id: str, n: int, steps: int, x64: bool) -> dict[str, float]:
    """Env-steps/s of the scan and the Python loop, and the compile seconds of each."""
    with jax.enable_x64(x64):
        env, params = make_jax(env_id)
        m = env.num_actions
        step = jax.vmap(env.step, in_axes=(0, 0, 0, None))
        keys = jax.random.split(jax.random.key(0), n)
        _, state = jax.vmap(env.reset, in_axes=(0, None))(keys, params)

        def body(carry, _):
            key, state = carry
            key, k_act, k_step = jax.random.split(key, 3)
            actions = jax.random.uniform(k_act, (n, m), minval=-1.0, maxval=1.0)
            obs, state, reward, terminated, truncated, _ = step(jax.random.split(k_step, n), state, actions, params)
            return (key, state), reward.mean()

        @jax.jit
        def run(key, state):
            return jax.lax.scan(body, (key, state), None, length=steps)

        t0 = time.perf_counter()
        jax.block_until_ready(run(jax.random.key(1), state))
        compile_scan = time.perf_counter() - t0
        t0 = time.perf_counter()
        jax.block_until_ready(run(jax.random.key(2), state))
        scan = n * steps / (time.perf_counter() - t0)

        # One compiled call per step, returning to numpy everything the native vector environment's
        # step returns (float32 observations, rewards, flags and the info arrays), with the episodes'
        # memory and the random key kept on JAX's side: the least any numpy boundary that calls the
        # compiled step once per step can pay.
        @jax.jit
        def call(key, state, actions):
            key, sub = jax.random.split(key)
            obs, state, reward, terminated, truncated, info = env.step_batch(sub, state, actions, params)
            shown = (obs.astype(jnp.float32), reward, terminated, truncated, info["phi"], info["abs_phi"],
                     info["abs_phi_sf"], info["force"], info["status"], state.s, state.time)
            return key, state, shown

        rng = np.random.default_rng(0)
        actions = [rng.uniform(-1, 1, (n, m)) for _ in range(8)]
        key = jax.random.key(3)
        t0 = time.perf_counter()
        jax.block_until_ready(call(key, state, actions[0]))
        compile_loop = time.perf_counter() - t0
        loop_steps = max(20, steps // 4)
        t0 = time.perf_counter()
        for i in range(loop_steps):
            key, state, shown = call(key, state, actions[i % 8])
            [np.asarray(x) for x in shown]
        loop = n * loop_steps / (time.perf_counter() - t0)
    return {"scan": scan, "loop": loop, "compile_scan": compile_scan, "compile_loop": compile_loop}


def native_rate(env_id: str, n: int, steps: int) -> float:
    venv = gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point")
    venv.reset(seed=0)
    rng = np.random.default_rng(0)
    actions = [rng.uniform(-1, 1, venv.action_space.shape).astype(np.float32) for _ in range(8)]
    for i in range(20):
        venv.step(actions[i % 8])
    t0 = time.perf_counter()
    for i in range(steps):
        venv.step(actions[i % 8])
    return n * steps / (time.perf_counter() - t0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default="results/bench_jax_envs")
    args = ap.parse_args()
    sizes = [256] if args.quick else [256, 4096]
    rows = []
    for env_id in env_ids("v1", shipped_only=True):
        for n in sizes:
            steps = 20 if args.quick else max(50, 1_000_000 // n)
            native = native_rate(env_id, n, steps)
            row = {"env": env_id, "n": n, "native": native}
            for x64 in (False, True):
                r = jax_rates(env_id, n, steps, x64)
                row.update({f"{k}_{'f64' if x64 else 'f32'}": v for k, v in r.items()})
            rows.append(row)
            print(f"{env_id:28s} N={n:5d} native {native / 1e6:5.2f} M/s | scan f32 {row['scan_f32'] / 1e6:5.2f} "
                  f"f64 {row['scan_f64'] / 1e6:5.2f} M/s | loop f32 {row['loop_f32'] / 1e6:5.2f} "
                  f"f64 {row['loop_f64'] / 1e6:5.2f} M/s | compile {row['compile_scan_f64']:.1f} s", flush=True)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    meta = {"cpus": os.cpu_count(), "jax": jax.__version__, "backend": jax.default_backend()}
    (out / "bench_jax_envs.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    lines = [f"JAX {meta['jax']} on {meta['backend']} ({meta['cpus']} CPUs); env-steps/s, millions.", "",
             "| env | N | native vector env | JAX scan f32 | JAX scan f64 | JAX loop f32 | JAX loop f64 | "
             "scan f64 / native | compile (s) |", "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['env']} | {r['n']} | {r['native'] / 1e6:.2f} | {r['scan_f32'] / 1e6:.2f} | "
                     f"{r['scan_f64'] / 1e6:.2f} | {r['loop_f32'] / 1e6:.2f} | {r['loop_f64'] / 1e6:.2f} | "
                     f"{r['scan_f64'] / r['native']:.2f} | {r['compile_scan_f64']:.1f} |")
    (out / "bench_jax_envs.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
