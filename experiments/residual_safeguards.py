"""Which safeguard of residual reinforcement learning matters: residual PPO on a stateful base,
with and without each of them.  Writes results/residual_safeguards.md and .json.

    python experiments/residual_safeguards.py                 # 4 variants x 2 seeds x 1 M steps, about 15 minutes
    python experiments/residual_safeguards.py --quick         # a smoke run

Each run's learning curve is in its sidecar under ``<out>/runs``.  The variants
(``VARIANTS``) start from the shipped residual PPO settings (residual scale 0.2, initial log std
-2, the base action in the observation) and add a value-function warm-up (the policy frozen while
the critic learns the base's returns, `vnhc_gym.training.callbacks.ValueWarmup`), a smaller
residual scale and initial noise (0.1 and -3, as residual RL papers start), or both.
The base is the cell's best classical baseline with its shipped tuned settings (by default the
observer law on the boat's ``noisy`` scenario, a base with internal state).  Every number is a
validation score (seeds from 5 000): the base's (the untrained agent's, step 0), the best
checkpoint's and the final model's; a run *beats its base* when the lower end of its best
checkpoint's interval is above the base's score.
"""

from __future__ import annotations

import argparse
import json
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

#: name -> (value warm-up as a fraction of the budget, residual scale, initial log std)
VARIANTS: dict[str, tuple[float, float, float]] = {
    "shipped": (0.0, 0.2, -2.0),
    "warm-up": (0.2, 0.2, -2.0),
    "small": (0.0, 0.1, -3.0),
    "warm-up + small": (0.2, 0.1, -3.0),
}


def one(variant: str, env: str, scenario: str, base: str, seed: int, steps: int, out: str) -> dict[str, Any]:
    from vnhc_gym.benchmark import settings
    from vnhc_gym.training import TrainConfig, train
    from vnhc_gym.training.config import resolve_env_id
    from vnhc_gym.training.hyperparams import load_hyperparams

    warmup, scale, log_std = VARIANTS[variant]
    hp = load_hyperparams("residual_ppo", resolve_env_id(env))
    overrides: dict[str, Any] = {
        "env_wrapper": [("vnhc_gym.wrappers.ResidualAction", {"scale": scale, "observe_base": True})],
        "policy_kwargs": {**hp["policy_kwargs"], "log_std_init": log_std},
    }
    if warmup > 0:
        overrides["callback"] = [("vnhc_gym.training.callbacks.ValueWarmup", {"steps": int(warmup * steps)})]
    cfg = TrainConfig(algo="residual_ppo", env=env, scenario=scenario, seed=seed, n_timesteps=steps, out=out,
                      test_episodes=0, threads=1, overrides=overrides, residual_base=base,
                      residual_base_settings=settings().get(env, {}).get(scenario, {}).get(base, {}),
                      name=f"{env}-{scenario}-{variant.replace(' ', '').replace('+', '_')}-s{seed}")
    curve = train(cfg)["curve"]
    start, best = curve[0], max(curve, key=lambda p: p["score"])
    return {"variant": variant, "seed": seed, "base": start["score"], "best": best["score"],
            "best_low": best["score_low"], "best_steps": best["steps"], "final": curve[-1]["score"],
            "beats_base": bool(best["score_low"] > start["score"])}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a smoke run (CI)")
    ap.add_argument("--env", default="usv")
    ap.add_argument("--scenario", default="noisy")
    ap.add_argument("--base", default="observer")
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("-n", "--n-timesteps", type=int, default=1_000_000)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--out", default="results/residual_safeguards")
    args = ap.parse_args()
    steps, seeds = (16_384, 1) if args.quick else (args.n_timesteps, args.seeds)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    jobs = [(v, args.env, args.scenario, args.base, s, steps, str(out / "runs"))
            for v in VARIANTS for s in range(seeds)]
    with ProcessPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        rows = list(pool.map(one, *zip(*jobs, strict=True)))
    (out / "residual_safeguards.json").write_text(json.dumps(rows, indent=1))
    lines = [f"Residual PPO on `{args.env}` `{args.scenario}`, base: `{args.base}` (tuned), {steps:,} steps, "
             f"{seeds} seed(s); validation scores (the base's is the untrained agent's).", "",
             "| variant | base | best checkpoint | final model | final / base | runs that beat their base |",
             "|---|---:|---:|---:|---:|---:|"]
    for v in VARIANTS:
        rs = [r for r in rows if r["variant"] == v]
        base, best, final = (float(np.mean([r[k] for r in rs])) for k in ("base", "best", "final"))
        lines.append(f"| {v} | {base:.4f} | {best:.4f} | {final:.4f} | {final / base:.3f} | "
                     f"{sum(r['beats_base'] for r in rs)}/{len(rs)} |")
    (out / "residual_safeguards.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
