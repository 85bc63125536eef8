"""Environment speed: a single step against Gymnasium's Pendulum-v1, and the native vector
environments against SyncVectorEnv and Gymnasium's native CartPoleVectorEnv.  Writes
results/bench_envs.md and .json.

    python experiments/bench_envs.py            # about 2 minutes
    python experiments/bench_envs.py --quick    # a smoke run

Vector throughput counts every sub-environment step of uniform random actions over repeated
episodes (resets included).  Gymnasium's environments run on one thread; XLA runs the compiled step
with the threads it chooses (up to about 1.6 cores busy here at large N).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
from gymnasium.envs.classic_control.cartpole import CartPoleVectorEnv

from vnhc_gym.tasks import env_ids


def single_step_us(env: gym.Env, n: int) -> float:
    env.reset(seed=0)
    a = np.zeros(env.action_space.shape, dtype=np.float32)
    for _ in range(200):
        env.step(a)
    best = np.inf
    for _ in range(5):
        t0 = time.perf_counter()
        for _ in range(n):
            _, _, term, trunc, _ = env.step(a)
            if term or trunc:
                env.reset()
        best = min(best, (time.perf_counter() - t0) / n)
    return best * 1e6


def vector_rate(venv: gym.vector.VectorEnv, steps: int) -> float:
    venv.reset(seed=0)
    rng = np.random.default_rng(0)
    actions = [venv.action_space.sample() for _ in range(8)] if not isinstance(venv.action_space, gym.spaces.Box) \
        else [rng.uniform(-1, 1, venv.action_space.shape).astype(np.float32) for _ in range(8)]
    for i in range(20):
        venv.step(actions[i % 8])
    t0 = time.perf_counter()
    for i in range(steps):
        venv.step(actions[i % 8])
    return venv.num_envs * steps / (time.perf_counter() - t0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default="results/bench_envs")
    args = ap.parse_args()
    n = 500 if args.quick else 20000
    single = {"Pendulum-v1": single_step_us(gym.make("Pendulum-v1").unwrapped, n)}
    for env_id in env_ids("v1"):
        single[env_id] = single_step_us(gym.make(env_id).unwrapped, n)
    for k, v in single.items():
        print(f"single step {k:28s} {v:7.2f} us  ({v / single['Pendulum-v1']:.2f} x Pendulum-v1)", flush=True)
    # The quick run's one size, 8, is the single environment's padded batch: one compilation per task.
    sizes = [8] if args.quick else [16, 256, 1024, 4096]
    rows = []
    for size in sizes:
        steps = max(20, 400_000 // size) if not args.quick else 50
        cart = vector_rate(CartPoleVectorEnv(num_envs=size), steps)
        for env_id in env_ids("v1"):
            native = vector_rate(gym.make_vec(env_id, num_envs=size, vectorization_mode="vector_entry_point"), steps)
            sync = vector_rate(gym.make_vec(env_id, num_envs=size, vectorization_mode="sync"),
                               max(5, steps // 20)) if size <= 1024 else None
            rows.append({"env": env_id, "n": size, "native": native, "sync": sync, "cartpole": cart})
            shown = "-" if sync is None else f"{sync / 1e3:.1f}"
            print(f"N={size:5d} {env_id:28s} native {native / 1e3:9.1f} k/s  sync {shown:>7s} k/s  "
                  f"CartPoleVectorEnv {cart / 1e3:9.1f} k/s", flush=True)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench_envs.json").write_text(json.dumps({"single_us": single, "vector": rows}, indent=1))
    lines = ["| env | single step (us) | / Pendulum-v1 |", "|---|---:|---:|"]
    lines += [f"| {k} | {v:.2f} | {v / single['Pendulum-v1']:.2f} |" for k, v in single.items()]
    lines += ["", "| env | N | native (env-steps/s) | SyncVectorEnv | native / Sync | CartPoleVectorEnv |",
              "|---|---:|---:|---:|---:|---:|"]
    for r in rows:
        # SyncVectorEnv is not run at the largest N (minutes for one number): "-" there.
        sync, ratio = ("-", "-") if r["sync"] is None else (f"{r['sync'] / 1e3:.1f} k",
                                                              f"{r['native'] / r['sync']:.0f}x")
        lines.append(f"| {r['env']} | {r['n']} | {r['native'] / 1e3:.0f} k | {sync} | {ratio} | "
                     f"{r['cartpole'] / 1e3:.0f} k |")
    (out / "bench_envs.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
