"""The learned-vs-classical comparison: every registered task and scenario, the classical baselines,
the oracle and the learned agents, scored on held-out episodes.

The grid (``GRID``): every registered task x 6 scenarios x {the oracle and the informed filter (the
headroom references), the k = 5 law, the tuned law (gain and variant), the safety-filtered law, the observer law, the
Kalman-filter law, the adaptive law, PPO (on Stable-Baselines3 and compiled), residual PPO on the
cell's best classical baseline (Stable-Baselines3), PPO with a history of 4 observations
(compiled)}, and the planning baseline (MPC within the force bound) on nominal and saturated; 5
training seeds on nominal and on the three scenarios where the law is weakest (noisy, mismatch,
disturbance), 3 on the others; 2 M env steps per learned run (``LEARNERS`` says why each learner
trains where it does).  ``--large`` is the bigger grid (10 seeds everywhere, 5 M steps).  It runs
through ``vnhc-gym sweep``'s code path: resumable (each finished run is saved at once and skipped on
a rerun, so the grid can run over several sittings), on a process pool or a Ray cluster; then it
writes the report (the score's intervals, the verdict per cell, steps and seconds to parity,
learning curves, the verdict figure, a performance profile) to ``<out>/report``.

    python experiments/train_compare.py                       # the default grid, about 10 hours on 2 cores
    python experiments/train_compare.py --quick               # a minute or two: two tasks, the pipeline end to end
    python experiments/train_compare.py --large --out results/large   # more seeds, longer budgets
    python experiments/train_compare.py --learners ppo residual_ppo ppo_history sac residual_sac   # SAC too
    python experiments/train_compare.py --learners ppo residual_ppo --backend jax   # these learners compiled
    python experiments/train_compare.py --executor ray --address <head>:6379   # on a cluster
    python experiments/train_compare.py --publish docs/results/train_compare   # copy the report there
    python experiments/train_compare.py --records docs/results/train_compare/runs.jsonl.gz   # continue it
    python experiments/train_compare.py --records docs/results/train_compare/runs.jsonl.gz --report-only

``--publish`` also writes every finished run's record (``runs.jsonl.gz``: the test episodes'
metrics, learning curves and settings) beside the report, so that anyone can recompute the
statistics; ``--records`` starts from such a file (its runs are skipped, and included in the report).
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

from vnhc_gym.sweep import (
    CLASSICAL_ALGOS,
    LEARNED_ALGOS,
    PLANNING_ALGOS,
    REFERENCE_ALGOS,
    grid,
    report,
    restore_records,
    run_sweep,
    save_records,
)
from vnhc_gym.tasks import TASKS

#: The tasks of ``--quick``: the two with the cheapest training steps.
QUICK_TASKS = ("sled", "cartpole")

SCENARIOS = ["nominal", "saturated", "mismatch", "noisy", "coarse", "disturbance", "delay", "lag", "unmodelled"]
#: Five seeds where the law is weakest and on nominal, three elsewhere.
SEEDS = {"nominal": range(5), "noisy": range(5), "mismatch": range(5), "disturbance": range(5),
         "saturated": range(3), "coarse": range(3), "delay": range(5), "lag": range(5), "unmodelled": range(5)}
#: The learned agents of the default grid and the backend each trains on: PPO on both (the report's
#: ``backends.md`` places the compiled runs against SB3's, cell by cell), residual PPO on
#: Stable-Baselines3 (its base is the cell's best classical baseline, which the compiled backend offers
#: only among the laws and the Kalman filter) and PPO with history compiled (the faster backend).
#: ``--learners`` (any of ``vnhc_gym.sweep.LEARNED_ALGOS``) with ``--backend`` replaces them.
LEARNERS = [("ppo", "sb3"), ("residual_ppo", "sb3"), ("ppo", "jax"), ("ppo_history", "jax")]
#: Budgets (env steps) of the learners that do not take the grid's: SAC's file budget of 1 M (an
#: off-policy env step costs about 15x a PPO one here).
BUDGETS = {"sac": 1_000_000, "residual_sac": 1_000_000}
#: The planning baseline (a solve every control step) where the force bound decides: nominal and saturated.
PLANNING = {"algos": list(PLANNING_ALGOS), "scenarios": ["nominal", "saturated"]}
CLASSICAL = [*REFERENCE_ALGOS, *(a for a in CLASSICAL_ALGOS if a not in PLANNING_ALGOS)]
GRID = {"scenarios": SCENARIOS, "n_timesteps": 2_000_000}
LARGE = {"seeds": range(10), "n_timesteps": 5_000_000}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="tiny budgets, one scenario, one seed, two tasks (CI)")
    ap.add_argument("--large", action="store_true", help="10 seeds in every cell and 5 M steps per learned run")
    ap.add_argument("--learners", nargs="+", choices=list(LEARNED_ALGOS),
                    help="the learned agents of the grid, all on --backend (default: "
                         f"{', '.join(f'{a} on {b}' for a, b in LEARNERS)})")
    ap.add_argument("--algos", nargs="+", choices=[*CLASSICAL, *LEARNED_ALGOS, *PLANNING_ALGOS],
                    help="run only these algorithms of the grid (the same runs, so a later full run skips them); "
                         "the report covers every finished run")
    ap.add_argument("--backend", choices=["sb3", "jax"],
                    help="where the --learners train (default sb3): sb3, or jax (compiled with their environment, a "
                         "cell's seeds in one program; reported as ppo-jax and so on beside sb3's rows)")
    ap.add_argument("--out", default="results/train_compare")
    ap.add_argument("--executor", choices=["local", "ray"], default="local")
    ap.add_argument("--address", default=None)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--publish", metavar="DIR", help="copy the report's tables and figures to DIR, and put its "
                    "headline table in the README (between the results markers)")
    ap.add_argument("--records", metavar="FILE", help="start from the run records of a published report "
                    "(runs.jsonl.gz): those runs are skipped and included in the report")
    ap.add_argument("--report-only", action="store_true",
                    help="run nothing: make the report (and --publish, --ship) from the finished runs in --out")
    ap.add_argument("--ship", action="store_true",
                    help="copy the nominal agent of median validation score (over the seeds) of each task and "
                         "algorithm into vnhc_gym/agents_zoo and the classical settings chosen per cell into "
                         "vnhc_gym/baselines/settings.json")
    args = ap.parse_args()
    tasks = list(TASKS)
    if args.quick:
        tasks = list(QUICK_TASKS)  # the pipeline is the same code for every task; the tests cover each task's runs
        specs = grid(tasks, ["nominal"], ["oracle", "law", "tuned_law", "observer", "ppo", "residual_ppo"], [0], 2048,
                     test_episodes=4, eval_episodes=4)
        jobs = 1
    else:
        size = LARGE if args.large else GRID
        seeds = {} if args.large else {k: list(v) for k, v in SEEDS.items()}
        specs = grid(tasks, GRID["scenarios"], CLASSICAL, list(LARGE["seeds"]) if args.large else [0],
                     size["n_timesteps"])
        learners = LEARNERS
        if args.learners or args.backend:
            names = args.learners or list(dict.fromkeys(a for a, _ in LEARNERS))
            learners = [(a, args.backend or "sb3") for a in names]
        for learner, backend in learners:
            budget = BUDGETS.get(learner, GRID["n_timesteps"]) * size["n_timesteps"] // GRID["n_timesteps"]
            specs += grid(tasks, GRID["scenarios"], [learner], list(LARGE["seeds"]) if args.large else [0], budget,
                          seeds_by_scenario=seeds, backend=backend)
        specs += grid(tasks, PLANNING["scenarios"], PLANNING["algos"], [0], size["n_timesteps"])
        jobs = args.jobs
    if args.algos:
        specs = [s for s in specs if s.algo in args.algos]
    # The classical and reference runs first (a few seconds each): every residual run then reads its
    # cell's best classical baseline from them instead of tuning it again, and the tuned settings of
    # every task are saved before the first learned run starts.
    specs.sort(key=lambda s: s.learned)
    if args.records:
        print(f"{restore_records(args.records, args.out)} runs restored from {args.records}")
    if not args.report_only:
        run_sweep(specs, args.out, executor=args.executor, jobs=jobs, threads=1, address=args.address)
    report(args.out)
    if args.publish:
        dest = Path(args.publish)
        dest.mkdir(parents=True, exist_ok=True)
        for f in (Path(args.out) / "report").iterdir():
            shutil.copy(f, dest / f.name)
        n = save_records(args.out, dest / "runs.jsonl.gz")
        print(f"report and {n} run records copied to {dest}")
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


def validation_score(run: dict) -> float:
    """The validation score of a learned run's saved model: its learning curve's point at
    ``best_steps`` (the best checkpoint, the model ``<stem>.zip`` holds and the package would ship).

    Raises
    ------
    ValueError
        If the run's sidecar has no validated point at ``best_steps``.
    """
    best = run.get("best_steps")
    points = [p for p in run.get("curve") or [] if p.get("steps") == best and "score" in p]
    if best is None or not points:
        raise ValueError(f"run {run.get('name')!r} has no validation score at its best checkpoint "
                         f"(best_steps {best!r})")
    return float(points[0]["score"])


def median_seed(runs: list[dict]) -> dict:
    """The run of median validation score among a cell's seeds (the upper median of an even
    number; equal scores keep the seeds' order).  The test episodes choose nothing: they only score."""
    import numpy as np

    if not runs:
        raise ValueError("no runs to choose from")
    scores = [validation_score(r) for r in runs]
    return runs[int(np.argsort(scores, kind="stable")[len(scores) // 2])]


def ship(out: Path) -> None:
    """The settings the package ships (the classical baselines' and the oracle's, per cell) and its
    agents (of each task and algorithm whose nominal cell is finished, the nominal seed of median
    validation score, `median_seed`)."""
    import json

    from vnhc_gym.sweep import load_runs

    root = Path(__file__).resolve().parent.parent / "vnhc_gym"
    runs = load_runs(out)
    settings: dict[str, dict[str, dict[str, dict]]] = {}
    for r in runs:
        spec = r["spec"]
        if spec["algo"] in CLASSICAL_ALGOS + REFERENCE_ALGOS:
            settings.setdefault(spec["env"], {}).setdefault(spec["scenario"], {})[spec["algo"]] = r["settings"]
    (root / "baselines" / "settings.json").write_text(json.dumps(settings, indent=1, sort_keys=True) + "\n")
    for task in TASKS:
        for algo in dict.fromkeys(a for a, b in LEARNERS if b == "sb3"):  # the zoo holds SB3 models
            rs = [r for r in runs if r["spec"]["env"] == task and r["spec"]["scenario"] == "nominal"
                  and r["spec"]["algo"] == algo and r["spec"].get("backend", "sb3") == "sb3"]
            if len(rs) < len(SEEDS["nominal"]):  # only from a finished cell
                print(f"not shipping {task}-{algo}: {len(rs)} of {len(SEEDS['nominal'])} nominal runs finished")
                continue
            median = median_seed(rs)
            stem = f"{task}-{algo}"
            model = out / "runs" / f"{median['name']}.zip"
            if not model.exists():  # a run restored from published records has no model file
                print(f"not shipping {stem}: {model} is not here (rerun that seed to make it)")
                continue
            shutil.copy(model, root / "agents_zoo" / f"{stem}.zip")
            side = {**median, "name": algo, "shipped_from": median["name"]}
            (root / "agents_zoo" / f"{stem}.json").write_text(json.dumps(side, indent=1) + "\n")
            print(f"shipped {stem} (seed {median['spec']['seed']})")


if __name__ == "__main__":
    main()
