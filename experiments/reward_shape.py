"""Choose the width sigma of the bounded reward exp(-|phi~| / sigma) by measurement.

For each task and sigma: PPO from scratch (the default hyperparameters, a fixed budget) on the
nominal scenario, tested on held-out episodes, and the reward each baseline policy would collect.
Writes results/reward_shape.md and .json.

    python experiments/reward_shape.py                 # about 10 minutes on 2 cores
    python experiments/reward_shape.py --steps 100000  # a quick look
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from vnhc_gym.baselines import GeometricController, ZeroPolicy
from vnhc_gym.evaluation import evaluate
from vnhc_gym.tasks import env_id
from vnhc_gym.training import TrainConfig, train


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=500_000)
    ap.add_argument("--sigmas", type=float, nargs="+", default=[0.03, 0.1, 0.3, 1.0])
    ap.add_argument("--tasks", nargs="+", default=["flocking", "usv"])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--out", default="results/reward_shape")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for task in args.tasks:
        eid = env_id(task)
        law = evaluate(GeometricController, eid, n_episodes=20)
        zero = evaluate(ZeroPolicy, eid, n_episodes=20)
        for sigma in args.sigmas:
            for seed in args.seeds:
                meta = train(TrainConfig(algo="ppo", env=task, seed=seed, n_timesteps=args.steps, out=str(out / "runs"),
                                         name=f"{task}-sigma{sigma}-s{seed}", env_kwargs={"reward_sigma": sigma}))
                s = meta["test"]["summary"]
                rows.append({"task": task, "sigma": sigma, "seed": seed, "ppo_mean_abs_phi": s["mean_abs_phi"][0],
                             "ppo_mean_abs_phi_sf": s["mean_abs_phi_sf"][0], "ppo_terminated": s["terminated"][0],
                             "law_mean_abs_phi": float(np.median(law.metrics["mean_abs_phi"])),
                             "zero_reward": float(np.mean(np.exp(-zero.metrics["mean_abs_phi_sf"] / sigma))),
                             "law_reward": float(np.mean(np.exp(-law.metrics["mean_abs_phi_sf"] / sigma)))})
                print(rows[-1], flush=True)
    (out / "reward_shape.json").write_text(json.dumps(rows, indent=1))
    lines = ["| task | sigma | seed | PPO mean abs phi | PPO mean abs phi~ | law mean abs phi | PPO terminated |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['task']} | {r['sigma']:g} | {r['seed']} | {r['ppo_mean_abs_phi']:.3g} | "
                     f"{r['ppo_mean_abs_phi_sf']:.3g} | {r['law_mean_abs_phi']:.3g} | {r['ppo_terminated']:.2f} |")
    (out / "reward_shape.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
