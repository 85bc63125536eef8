"""Does the planning baseline's state-limit penalty matter?  MPC with and without it.

For each task whose state limits (``Task.limits``) the plan sees, and each scenario, the planning baseline at each gain
of its tuning grid, with the penalty (``limit_weight=1e4``) and without (``0``), on validation
episodes: the mean score and the share of episodes finished.  Writes
``<out>/mpc_limits.md`` and ``.json``.

    python experiments/mpc_limits.py                       # about 10 minutes on one core
    python experiments/mpc_limits.py --tasks cartpole --scenarios saturated
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import gymnasium as gym

from vnhc_gym.baselines.mpc import MPCController
from vnhc_gym.baselines.tuning import CLASSICAL
from vnhc_gym.evaluation import VALIDATION_SEED, evaluate
from vnhc_gym.tasks import TASKS, env_id


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    # The tasks whose limits the plan sees: limits in the environment's state, which the controller
    # model shares (the boat's controller model is written relative to the water).
    tasks = {name: gym.make(env_id(name)).unwrapped.task for name in TASKS}
    with_limits = [name for name, t in tasks.items() if t.limits and t.controller_model() is t.model]
    ap.add_argument("--tasks", nargs="+", default=with_limits, choices=with_limits)
    ap.add_argument("--scenarios", nargs="+", default=["saturated", "nominal"])
    ap.add_argument("--weights", type=float, nargs="+", default=[0.0, 1e4])
    ap.add_argument("--episodes", type=int, default=20)
    ap.add_argument("--out", default="docs/results/mpc_limits")
    args = ap.parse_args()
    rows = []
    for task in args.tasks:
        for scenario in args.scenarios:
            for gain in CLASSICAL["mpc"][1]["gain"]:
                for weight in args.weights:
                    res = evaluate(lambda env, g=gain, w=weight: MPCController(env, gain=g, limit_weight=w),
                                   env_id(task), scenario, n_episodes=args.episodes, seed=VALIDATION_SEED)
                    rows.append({"task": task, "scenario": scenario, "gain": gain, "limit_weight": weight,
                                 "score": float(res.metrics["score"].mean()),
                                 "success": float(res.metrics["success"].mean())})
                    print(rows[-1], flush=True)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "mpc_limits.json").write_text(json.dumps(rows, indent=1) + "\n")
    lines = ["| task | scenario | gain | limit_weight | mean score | finished |", "|---|---|---:|---:|---:|---:|"]
    lines += [f"| {r['task']} | {r['scenario']} | {r['gain']:g} | {r['limit_weight']:g} | {r['score']:.4f} | "
              f"{r['success']:.2f} |" for r in rows]
    (out / "mpc_limits.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
