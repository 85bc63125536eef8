"""PPO training throughput through the native vector environments: env-steps per second at several
batch sizes, with the rollout (environment + policy inference) and update (gradient steps) shares,
and the effect of torch's thread count.  Writes results/bench_train.md and .json.

    python experiments/bench_train.py              # about 4 minutes on 2 cores
    python experiments/bench_train.py --quick      # a smoke run

The environment kernels run on one thread (numba, no thread pool), so only torch's threads can
compete for the cores; at 256 environments the run compares one torch thread with two (the
default of ``vnhc-gym train``).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback

import vnhc_gym
from vnhc_gym.tasks import env_id


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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer steps and sizes (CI)")
    ap.add_argument("--out", default="results/bench_train")
    args = ap.parse_args()
    steps = 16384 if args.quick else 196_608
    sizes = [8, 64] if args.quick else [8, 64, 256, 1024]
    rows = []
    for task in ("flocking", "usv"):
        for n in sizes:
            for threads in ([1] if n != 256 or args.quick else [1, 2]):
                rows.append(measure(task, n, threads, steps))
                r = rows[-1]
                print(f"{task:9s} n_envs={n:5d} threads={threads}  {r['steps_per_s'] / 1e3:7.1f} k env-steps/s  "
                      f"rollout {100 * r['rollout_share']:4.1f} %  update {100 * (1 - r['rollout_share']):4.1f} %",
                      flush=True)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench_train.json").write_text(json.dumps(rows, indent=1))
    lines = ["| task | n_envs | torch threads | k env-steps/s | rollout share | update share |",
             "|---|---:|---:|---:|---:|---:|"]
    lines += [f"| {r['task']} | {r['n_envs']} | {r['threads']} | {r['steps_per_s'] / 1e3:.1f} | "
              f"{100 * r['rollout_share']:.0f} % | {100 * (1 - r['rollout_share']):.0f} % |" for r in rows]
    (out / "bench_train.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
