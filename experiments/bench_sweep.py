"""The cost of running a sweep on Ray instead of in-process: the same tiny grid (2 tasks x 1 scenario
x 2 seeds of a few thousand steps, plus the k = 5 law) both ways, with their wall times and the
evaluation numbers, which must agree.  Writes results/bench_sweep.md.

    python experiments/bench_sweep.py
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
import time
from pathlib import Path

from vnhc_gym.sweep import grid, load_runs, run_sweep


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=4096)
    ap.add_argument("--out", default="results/bench_sweep.md")
    args = ap.parse_args()
    specs = grid(["flocking", "usv"], ["nominal"], ["law", "ppo"], [0, 1], args.steps, test_episodes=5,
                 eval_episodes=5)
    walls, numbers = {}, {}
    for executor in ("local", "ray"):
        tmp = Path(tempfile.mkdtemp())
        try:
            t0 = time.perf_counter()
            run_sweep(specs, tmp, executor=executor, log=lambda s: None)
            walls[executor] = time.perf_counter() - t0
            numbers[executor] = {r["name"]: r["test"]["metrics"]["mean_abs_phi"] for r in load_runs(tmp)}
        finally:
            shutil.rmtree(tmp)
    same = numbers["local"] == numbers["ray"]
    n = len(specs)
    lines = ["| executor | runs | wall (s) | per run (s) |", "|---|---:|---:|---:|"]
    lines += [f"| {k} | {n} | {v:.1f} | {v / n:.2f} |" for k, v in walls.items()]
    lines += ["", f"Ray overhead: {walls['ray'] - walls['local']:+.1f} s for {n} runs "
              f"({(walls['ray'] - walls['local']) / n:+.2f} s per run, Ray's start-up included); "
              f"identical evaluation numbers: {'yes' if same else 'NO'}"]
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    print(json.dumps({"walls": walls, "identical": same}))


if __name__ == "__main__":
    main()
