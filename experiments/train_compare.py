"""The learned-vs-classical comparison: every task and scenario, classical baselines and learned agents.

The grid (``GRID``): 2 environments x 6 scenarios x {the k = 5 law, the tuned law, the observer
law, the adaptive law, PPO, residual PPO, PPO with a history of 4 observations}, 5 training seeds on
nominal and on the three scenarios where the law is weakest (noisy, mismatch, disturbance), 3 on the
others.  It runs through ``vnhc-gym sweep``'s code path (resumable: finished runs are kept and
skipped, so it can run over several sittings), then writes the report (rliable statistics,
steps- and seconds-to-parity, learning curves, performance profile) to ``<out>/report``.

    python experiments/train_compare.py                       # the full grid, about 2 hours on 2 cores
    python experiments/train_compare.py --quick               # a few minutes: the pipeline end to end
    python experiments/train_compare.py --executor ray --address <head>:6379   # on a cluster
    python experiments/train_compare.py --publish docs/results/train_compare   # copy the report there
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

from vnhc_gym.sweep import CLASSICAL_ALGOS, LEARNED_ALGOS, grid, report, run_sweep

SCENARIOS = ["nominal", "saturated", "mismatch", "noisy", "coarse", "disturbance"]
#: Five seeds where the law is weakest and on nominal, three elsewhere.
SEEDS = {"nominal": range(5), "noisy": range(5), "mismatch": range(5), "disturbance": range(5),
         "saturated": range(3), "coarse": range(3)}
GRID = {"envs": ["flocking", "usv"], "scenarios": SCENARIOS, "algos": [*CLASSICAL_ALGOS, *LEARNED_ALGOS],
        "n_timesteps": 2_000_000}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="tiny budgets, one scenario, one seed (CI)")
    ap.add_argument("--out", default="results/train_compare")
    ap.add_argument("--executor", choices=["local", "ray"], default="local")
    ap.add_argument("--address", default=None)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--publish", metavar="DIR", help="copy the report's tables and figures to DIR, and put its "
                    "headline table in the README (between the results markers)")
    ap.add_argument("--ship", action="store_true",
                    help="copy the median-seed nominal agent of each task and algorithm into vnhc_gym/agents_zoo and "
                         "the classical settings chosen per cell into vnhc_gym/baselines/settings.json")
    args = ap.parse_args()
    if args.quick:
        specs = grid(["flocking", "usv"], ["nominal"], ["law", "tuned_law", "ppo", "residual_ppo"], [0], 2048,
                     test_episodes=4, eval_episodes=4)
        jobs = 1
    else:
        specs = grid(GRID["envs"], GRID["scenarios"], GRID["algos"], [0], GRID["n_timesteps"],
                     seeds_by_scenario={k: list(v) for k, v in SEEDS.items()})
        jobs = args.jobs
    run_sweep(specs, args.out, executor=args.executor, jobs=jobs, threads=1, address=args.address)
    report(args.out)
    if args.publish:
        dest = Path(args.publish)
        dest.mkdir(parents=True, exist_ok=True)
        for f in (Path(args.out) / "report").iterdir():
            shutil.copy(f, dest / f.name)
        print(f"report copied to {dest}")
        readme = Path(__file__).resolve().parent.parent / "README.md"
        text = readme.read_text()
        begin, end = "<!-- results: begin -->", "<!-- results: end -->"
        if begin in text and end in text:
            head, _, rest = text.partition(begin)
            _, _, tail = rest.partition(end)
            table = (Path(args.out) / "report" / "headline.md").read_text()
            readme.write_text(f"{head}{begin}\n{table}{end}{tail}")
            print(f"headline table written into {readme}")
    if args.ship:
        ship(Path(args.out))


def ship(out: Path) -> None:
    """The agents and settings the package ships, from a finished comparison."""
    import json

    import numpy as np

    from vnhc_gym.sweep import load_runs

    root = Path(__file__).resolve().parent.parent / "vnhc_gym"
    runs = load_runs(out)
    settings: dict[str, dict[str, dict[str, dict]]] = {}
    for r in runs:
        spec = r["spec"]
        if spec["algo"] in CLASSICAL_ALGOS:
            settings.setdefault(spec["env"], {}).setdefault(spec["scenario"], {})[spec["algo"]] = r["settings"]
    (root / "baselines" / "settings.json").write_text(json.dumps(settings, indent=1, sort_keys=True) + "\n")
    for task in GRID["envs"]:
        for algo in LEARNED_ALGOS:
            rs = [r for r in runs if r["spec"]["env"] == task and r["spec"]["scenario"] == "nominal"
                  and r["spec"]["algo"] == algo]
            if not rs:
                continue
            scores = [float(np.median(r["test"]["metrics"]["mean_abs_phi_sf"])) for r in rs]
            median = rs[int(np.argsort(scores)[len(scores) // 2])]
            stem = f"{task}-{algo}"
            shutil.copy(out / "runs" / f"{median['name']}.zip", root / "agents_zoo" / f"{stem}.zip")
            side = {**median, "name": algo, "shipped_from": median["name"]}
            (root / "agents_zoo" / f"{stem}.json").write_text(json.dumps(side, indent=1) + "\n")
            print(f"shipped {stem} (seed {median['spec']['seed']})")


if __name__ == "__main__":
    main()
