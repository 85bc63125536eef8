"""Choose the reward's width sigma and shape by measurement.

For each task, shape (``bounded``: ``exp(-|phi~| / sigma)``; ``reciprocal``: ``1 / (1 + |phi~| /
sigma)``, the long tail) and sigma: an agent trained from scratch (the default hyperparameters, a
fixed budget) on the nominal scenario with that reward, its checkpoint chosen on validation
episodes and tested on held-out ones.  Validation and test always score with the environment's
default reward, so shapes are compared on one scale: the test score, the mean ``|phi~|`` and the
episodes finished.  Also the reward each baseline policy would collect.  Writes
<out>/reward_shape.md and .json.

    python experiments/reward_shape.py                 # the widths: about 10 minutes on 2 cores
    python experiments/reward_shape.py --steps 100000  # a quick look
    python experiments/reward_shape.py --tasks flocking --sigmas 0.3 --shapes bounded reciprocal \
        --algo sac --steps 1000000 --seeds 0 1 2       # the long tail against the exponential
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
    ap.add_argument("--shapes", nargs="+", default=["bounded"], choices=["bounded", "reciprocal"])
    ap.add_argument("--algo", default="ppo", help="a learner of vnhc-gym train (ppo, sac, ...)")
    ap.add_argument("--out", default="results/reward_shape")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for task in args.tasks:
        eid = env_id(task)
        law = evaluate(GeometricController, eid, n_episodes=20)
        zero = evaluate(ZeroPolicy, eid, n_episodes=20)
        for shape in args.shapes:
            for sigma in args.sigmas:
                for seed in args.seeds:
                    name = f"{task}-{args.algo}-{shape}-sigma{sigma}-s{seed}"
                    meta = train(TrainConfig(algo=args.algo, env=task, seed=seed, n_timesteps=args.steps,
                                             out=str(out / "runs"), name=name,
                                             env_kwargs={"reward": shape, "reward_sigma": sigma}))
                    s = meta["test"]["summary"]
                    rows.append({"task": task, "algo": args.algo, "shape": shape, "sigma": sigma, "seed": seed,
                                 "score": s["score"][0], "success": s["success"][0],
                                 "mean_abs_phi": s["mean_abs_phi"][0], "mean_abs_phi_sf": s["mean_abs_phi_sf"][0],
                                 "law_mean_abs_phi": float(np.median(law.metrics["mean_abs_phi"])),
                                 "law_score": float(np.mean(law.metrics["score"])),
                                 "zero_reward": float(np.mean(np.exp(-zero.metrics["mean_abs_phi_sf"] / sigma))),
                                 "law_reward": float(np.mean(np.exp(-law.metrics["mean_abs_phi_sf"] / sigma)))})
                    print(rows[-1], flush=True)
    (out / "reward_shape.json").write_text(json.dumps(rows, indent=1))
    lines = ["| task | algo | shape | sigma | seed | test score | finished | mean abs phi | mean abs phi~ "
             "| law mean abs phi | law score |",
             "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['task']} | {r['algo']} | {r['shape']} | {r['sigma']:g} | {r['seed']} | {r['score']:.4f} | "
                     f"{r['success']:.2f} | {r['mean_abs_phi']:.3g} | {r['mean_abs_phi_sf']:.3g} | "
                     f"{r['law_mean_abs_phi']:.3g} | {r['law_score']:.4f} |")
    (out / "reward_shape.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
