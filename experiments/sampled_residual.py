"""The sampled-data floor: how far ``|phi|`` falls when the law is held over each control period.

For every registered environment, gain and control period: the steady level (mean ``|phi|`` over
the second half of 20 s nominal episodes) of the plain law (evaluated once per period and held),
its sampled-data variant (the held control that makes ``phi`` after one period equal
``exp(-k dt) phi``), and the law inside every RK4 stage on the true state.  Writes
results/sampled_residual.md.

    python experiments/sampled_residual.py
"""

from __future__ import annotations

import argparse
from pathlib import Path

from vnhc_gym.baselines import GeometricController, ZeroPolicy
from vnhc_gym.evaluation import evaluate
from vnhc_gym.tasks import env_ids


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=5)
    ap.add_argument("--out", default="results/sampled_residual.md")
    args = ap.parse_args()
    lines = ["| env | k | dt (s) | plain | sampled | in-loop | plain / sampled |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    for env_id in env_ids("v1"):
        for k in (1.0, 5.0):
            for dt in (0.01, 0.05, 0.1):
                kw = {"dt": dt, "n_episodes": args.episodes}
                plain = evaluate(lambda e, k=k: GeometricController(e, gain=k), env_id, **kw)
                sampled = evaluate(lambda e, k=k: GeometricController(e, gain=k, variant="sampled"), env_id, **kw)
                inloop = evaluate(ZeroPolicy, env_id, feedback="continuous", gain=k, **kw)
                p, s, i = (r.summary()["late_abs_phi"].point for r in (plain, sampled, inloop))
                lines.append(f"| {env_id} | {k:g} | {dt:g} | {p:.3g} | {s:.3g} | {i:.3g} | {p / s:.3g} |")
                print(lines[-1], flush=True)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text("Steady level: mean |phi| over the second half of 20 s nominal episodes.\n\n"
                              + "\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
