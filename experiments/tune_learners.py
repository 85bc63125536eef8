"""Tuned learners from scratch against the tuned law: how close does learning get?

For each cell (task, scenario), learner and training reward: an Optuna study (``vnhc-gym tune``:
TPE, median pruning, validation episodes only) with the same budget for every learner (``--trials``
x ``--trial-steps`` env steps), then the winner and the shipped settings each trained from scratch
with ``--seeds`` training seeds at the hyperparameter file's full budget and tested on 20 held-out
episodes per seed.  The tuned law (the package's shipped gain for the cell) is tested on the same
episodes.  Per row: the test score (mean and 95 % interval over every test episode of every seed),
the share of episodes finished, the IQM of the episodes' mean ``|phi~|`` and its ratio to the tuned
law's (how many times the law's error).  A training reward other than the
environment's default (``--rewards reciprocal``: the long tail) changes only the training
environments; validation and test use the default reward, so every row is on one scale.

Everything is resumable: the studies live in ``<out>/tuned/<reward>/studies.db`` and each finished
training run's sidecar is kept (a rerun skips it); ``--jobs`` processes run the studies, then every
final run, one seed each.  ``--settings`` chooses the final runs (a study runs only for ``tuned``);
``--final-steps`` trains for another budget, and ``--variant LABEL KEY:VALUE ...`` the chosen settings
with a few hyperparameters replaced, each under a name of its own.  The report covers every finished
run of the cells in ``<out>/runs``, whichever invocation trained it: one row per learner, training
reward, settings and budget; the rows of an earlier report (``--publish``'s, else ``<out>``'s) whose
runs are not in ``<out>/runs`` are kept.  Writes ``<out>/tune_learners.md``, ``.json`` and ``.png``
(each row's validation curve beside the law's level on the same episodes), and the same files to
``--publish`` (there with the studies' storage, ``studies/<reward>.db``), with each study's cost in
core-hours (its trials' wall times) and each final run's training minutes.

    python experiments/tune_learners.py --cells usv/nominal --learners ppo --trials 4 --trial-steps 100000
    python experiments/tune_learners.py --rewards bounded --learners ppo          # both cells
    python experiments/tune_learners.py --cells flocking/nominal --rewards reciprocal --settings shipped \
        --learners sac --final-steps 1000000 3000000                              # two budgets
    python experiments/tune_learners.py --cells usv/nominal --learners sac --settings tuned \
        --final-steps 1000000 --variant te5 target_entropy:-5                    # a variant
    python experiments/tune_learners.py --report-only --publish docs/results/tune_learners
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from vnhc_gym.stats import iqm  # rliable's interquartile mean
from vnhc_gym.training.cli import parse_key_values  # the KEY:VALUE items of vnhc-gym train

CELLS = ["usv/nominal", "flocking/nominal"]
VALIDATION_EPISODES = 10  # as many as each training run's checkpoint evaluation (TrainConfig.eval_episodes)
LEARNERS = ["ppo", "sac"]


def _study(job: dict[str, Any]) -> None:
    """One (cell, learner, reward)'s study, when its winner is asked for (the shipped settings need none)."""
    import torch

    from vnhc_gym.training.tune import TuneConfig, tune

    torch.set_num_threads(1)
    task, scenario = job["cell"].split("/")
    where, tag, kept = _study_paths(job)
    where.mkdir(parents=True, exist_ok=True)
    # ``vnhc-gym tune`` adds ``trials`` to a stored study; a rerun of this script adds only the missing ones.
    # A study grown to its budget elsewhere (``vnhc-gym tune`` workers sharing its storage) only needs its
    # winner kept.
    done = _trials_so_far(where, tag)
    winner = where / f"{task}-{scenario}" / f"{job['algo']}.yml"
    if done < job["trials"] or not winner.exists():
        # Named even when it is the default: it overrides a hyperparameter file's own env_kwargs.
        tune(TuneConfig(algo=job["algo"], env=task, scenario=scenario, trials=max(1, job["trials"] - done),
                        n_timesteps=job["trial_steps"], out=str(where), study=tag,
                        env_kwargs={"reward": job["reward"]}),
             log=lambda line: print(line, flush=True))
    kept.write_text(winner.read_text())


def _study_paths(job: dict[str, Any]) -> tuple[Path, str, Path]:
    """A study's folder (one per reward: its studies' winners never collide), name and kept winner file."""
    task, scenario = job["cell"].split("/")
    tag = f"{task}-{scenario}-{job['algo']}-{job['reward']}"
    tuned = Path(job["out"]) / "tuned"
    return tuned / job["reward"], tag, tuned / f"{tag}.yml"


def _final_runs(job: dict[str, Any]) -> list[dict[str, Any]]:
    """The final training runs of one (cell, learner, reward) not finished yet, each a `_train` job."""
    runs = Path(job["out"]) / "runs"
    _, tag, kept = _study_paths(job)
    todo = []
    for steps in job["final_steps"]:
        # A run of a budget chosen here is named for its length: it never replaces a run of the file's budget.
        length = "" if steps is None else f"-{steps // 1000}k"
        for settings, hyperparams in (("shipped", None), ("tuned", str(kept))):
            # A variant (``--variant``) is the same settings with a few hyperparameters replaced.
            label = settings + (f"+{job['variant'][0]}" if job["variant"] else "")
            for seed in range(job["seeds"]) if settings in job["settings"] else ():
                name = f"{tag}-{label}-s{seed}{length}"
                if not (runs / f"{name}.json").exists():
                    todo.append({"cell": job["cell"], "algo": job["algo"], "seed": seed, "steps": steps,
                                 "out": str(runs), "name": name, "hyperparams": hyperparams,
                                 "overrides": job["variant"][1] if job["variant"] else {},
                                 "env_kwargs": {"reward": job["reward"]}})
    return todo


def _train(run: dict[str, Any]) -> None:
    """One final run: trained from scratch, its best checkpoint tested on the held-out episodes."""
    import torch

    from vnhc_gym.training import TrainConfig, train

    torch.set_num_threads(1)
    task, scenario = run["cell"].split("/")
    train(TrainConfig(algo=run["algo"], env=task, scenario=scenario, seed=run["seed"], n_timesteps=run["steps"],
                      out=run["out"], name=run["name"], hyperparams=run["hyperparams"],
                      overrides=run["overrides"], env_kwargs=run["env_kwargs"]))


#: A final run's name: ``<task>-<scenario>-<algo>-<reward>-<settings>[+<variant>]-s<seed>[-<k>k]``.
RUN_NAME = re.compile(r"^(?P<task>[a-z]+)-(?P<scenario>[a-z_]+)-(?P<algo>[a-z]+)-(?P<reward>[a-z]+)"
                      r"-(?P<settings>(?:shipped|tuned)(?:\+[a-z0-9_]+)?)-s(?P<seed>\d+)(?:-\d+k)?$")


def _rows(out: Path, cells: list[str]) -> list[dict[str, Any]]:
    """One row per (cell, learner, reward, settings, length) of every finished run in ``<out>/runs``."""
    groups: dict[tuple[str, ...], list[dict[str, Any]]] = {}
    for sidecar in sorted((out / "runs").glob("*.json")):
        meta = json.loads(sidecar.read_text())
        m = RUN_NAME.match(meta.get("name", ""))
        cell = f"{m['task']}/{m['scenario']}" if m else None
        if m is None or cell not in cells:
            continue
        key = (cell, m["algo"], m["reward"], m["settings"], str(meta["n_timesteps"]))
        groups.setdefault(key, []).append(meta)
    rows = []
    for (cell, algo, reward, settings, steps), metas in sorted(
            groups.items(), key=lambda kv: (cells.index(kv[0][0]), kv[0][1:4], int(kv[0][4]))):
        task, scenario = cell.split("/")
        study = out / "tuned" / reward / f"{task}-{scenario}" / f"{algo}-study.json"
        summary = json.loads(study.read_text()) if settings.startswith("tuned") and study.exists() else None
        # A variant's replaced hyperparameters, as the command gave them (RL Zoo's notation, e.g. lin_1e-3).
        replaced = dict(metas[0].get("config", {}).get("overrides", {}))
        rows.append({"cell": cell, "algo": algo, "reward": reward, "settings": settings, "steps": int(steps),
                     "replaced": replaced,
                     "seeds": [m["seed"] for m in metas],
                     "study_best_validation": summary["best_value"] if summary else None,
                     "study_trials": summary["n_trials"] if summary else None,
                     # What the study cost: every trial's wall time (a pruned trial stops early).
                     "study_seconds": sum(t["seconds"] or 0.0 for t in summary["trials"]) if summary else None,
                     "episodes": {k: [v for m in metas for v in m["test"]["metrics"][k]]
                                  for k in ("score", "success", "mean_abs_phi_sf")},
                     "train_seconds": [m["train_wall"] for m in metas],
                     # Each seed's validation curve: (steps, IQM mean |phi~| over the validation episodes).
                     "curves": [[(p["steps"], p["mean_abs_phi_sf"]) for p in m["curve"]] for m in metas]})
    return rows


def _key(row: dict[str, Any]) -> tuple[Any, ...]:
    return row["cell"], row["algo"], row["reward"], row["settings"], row.get("steps") or 0


def _merged(fresh: list[dict[str, Any]], kept: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The fresh rows, and those of ``kept`` (an earlier report's) that no fresh row replaces.

    A report is made from the runs on this machine; merging keeps the rows of runs trained elsewhere
    (another machine, a wiped cache), so that extending a published table never drops a row.  A cell's
    law row is recomputed whenever the cell is reported, so only the kept cells keep theirs.
    """
    have = {_key(r) for r in fresh}
    cells_here = {r["cell"] for r in fresh}
    rows = fresh + [r for r in kept if _key(r) not in have
                    and not (r["algo"] == "tuned_law" and r["cell"] in cells_here)]
    cells = list(dict.fromkeys(r["cell"] for r in rows))
    return sorted(rows, key=lambda r: (cells.index(r["cell"]), r["algo"] != "tuned_law", *_key(r)[1:]))


def _trials_so_far(where: Path, study: str) -> int:
    import optuna

    try:
        trials = optuna.load_study(study_name=study, storage=f"sqlite:///{(where / 'studies.db').resolve()}").trials
    except KeyError:  # no such study yet
        return 0
    # Trials of a killed process stay RUNNING (or end FAIL): only finished ones count toward the budget.
    return sum(t.state in (optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.PRUNED) for t in trials)


def _law(cell: str, episodes: int) -> dict[str, Any]:
    """The tuned law on the test episodes of every training seed (the same seeds as the agents')."""
    from vnhc_gym.baselines.tuning import evaluate_classical
    from vnhc_gym.benchmark import settings
    from vnhc_gym.evaluation import TEST_SEED, VALIDATION_SEED
    from vnhc_gym.tasks import env_id

    task, scenario = cell.split("/")
    gains = settings().get(task, {}).get(scenario, {}).get("tuned_law", {})
    res = evaluate_classical("tuned_law", gains, env_id(task), scenario, episodes, TEST_SEED)
    # The learners' curves are IQMs over the validation episodes of their checkpoints: the law's level on the same.
    val = evaluate_classical("tuned_law", gains, env_id(task), scenario, VALIDATION_EPISODES, VALIDATION_SEED)
    return {"cell": cell, "algo": "tuned_law", "reward": "-", "settings": json.dumps(gains),
            "episodes": {k: res.metrics[k].tolist() for k in ("score", "success", "mean_abs_phi_sf")},
            "validation_iqm": iqm(val.metrics["mean_abs_phi_sf"])}



def _cost(row: dict[str, Any]) -> str:
    """The study's and the final runs' cost, the two last columns of a row."""
    if row["algo"] == "tuned_law":
        return "- | -"
    # Only a tuned row has a study (none is stored for a winner copied in by hand).
    study = "-" if row.get("study_trials") is None else f"{row['study_trials']}, {row['study_seconds'] / 3600:.2f}"
    return f"{study} | {np.mean(row['train_seconds']) / 60:.1f}"


def _table(rows: list[dict[str, Any]]) -> str:
    from vnhc_gym.stats import interval_estimates

    law = {r["cell"]: iqm(np.asarray(r["episodes"]["mean_abs_phi_sf"])) for r in rows if r["algo"] == "tuned_law"}
    lines = ["| cell | agent | training reward | settings | steps | seeds | test score [95 % CI] | finished "
             "| IQM mean abs phi~ | x the tuned law's | study (trials, core-h) | training min/run |",
             "|---|---|---|---|---:|---:|---|---:|---:|---:|---:|---:|"]
    for r in rows:
        score = np.asarray(r["episodes"]["score"])
        iv = interval_estimates({"x": score[:, None]}, metric="mean", reps=2000)["x"]
        phi = iqm(np.asarray(r["episodes"]["mean_abs_phi_sf"]))
        steps = f"{r['steps'] / 1e6:g} M" if r.get("steps") else "-"
        seeds = len(r["seeds"]) if "seeds" in r else "-"
        settings = r["settings"] + "".join(f", {k} = {v}" for k, v in (r.get("replaced") or {}).items())
        lines.append(f"| {r['cell']} | {r['algo']} | {r['reward']} | {settings} | {steps} | {seeds} "
                     f"| {iv.point:.4f} [{iv.low:.4f}, {iv.high:.4f}] | {np.mean(r['episodes']['success']):.2f} "
                     f"| {phi:.3g} | {phi / law[r['cell']]:.1f} | {_cost(r)} |")
    return "\n".join(lines) + "\n"


def _plot(rows: list[dict[str, Any]], path: Path) -> None:
    """Per cell, each row's median validation curve over its seeds (log scale), and the tuned law's level."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cells = list(dict.fromkeys(r["cell"] for r in rows))
    fig, axes = plt.subplots(1, len(cells), figsize=(5.5 * len(cells), 4.0), squeeze=False)
    for ax, cell in zip(axes[0], cells, strict=True):
        for r in rows:
            if r["cell"] != cell:
                continue
            if r["algo"] == "tuned_law":
                ax.axhline(r["validation_iqm"], color="black", ls="--", lw=1, label="tuned law")
                continue
            n = min(len(c) for c in r["curves"])  # seeds of one row share their evaluation points
            steps = np.array([p[0] for p in r["curves"][0][:n]], dtype=float)
            phi = np.median([[p[1] for p in c[:n]] for c in r["curves"]], axis=0)
            ax.plot(steps[1:] / 1e6, phi[1:], lw=1.2,  # step 0 (the untrained net) would only stretch the axis
                    label=f"{r['algo']} {r['settings']} ({r['reward']}, {r['steps'] / 1e6:g} M)")
        ax.set_yscale("log")
        ax.set_title(cell, fontsize=10)
        ax.set_xlabel("env steps (millions)")
        ax.set_ylabel("validation IQM of mean |phi~| (median of seeds)")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cells", nargs="+", default=CELLS, help="task/scenario pairs")
    ap.add_argument("--learners", nargs="+", default=LEARNERS, choices=["ppo", "sac"])
    ap.add_argument("--rewards", nargs="+", default=["bounded"], choices=["bounded", "reciprocal"],
                    help="training rewards (each its own study)")
    ap.add_argument("--trials", type=int, default=20, help="trials per study (the same for every learner)")
    ap.add_argument("--trial-steps", type=int, default=300_000, help="env steps per trial")
    ap.add_argument("--seeds", type=int, default=3, help="training seeds of each final run")
    ap.add_argument("--final-steps", nargs="+", type=int, default=None, help="env steps of each final run, "
                    "one set of runs per value (default: the hyperparameter file's)")
    ap.add_argument("--settings", nargs="+", default=["shipped", "tuned"], choices=["shipped", "tuned"],
                    help="which final runs: the shipped hyperparameters, the study's winner, or both")
    ap.add_argument("--skip", nargs="*", default=[], metavar="CELL:LEARNER:REWARD",
                    help="combinations left out, e.g. usv/nominal:sac:reciprocal")
    ap.add_argument("--variant", nargs="+", default=None, metavar="LABEL KEY:VALUE",
                    help="final runs of the chosen settings with these hyperparameters replaced, named "
                         "<settings>+LABEL (e.g. te5 target_entropy:-5)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", default="results/tune_learners")
    ap.add_argument("--publish", default=None, help="also write the table, the figure and the rows' JSON "
                    "here (without the studies and the models)")
    ap.add_argument("--report-only", action="store_true", help="train nothing: the report of the finished runs")
    args = ap.parse_args()
    variant = None
    if args.variant:
        label, *items = args.variant
        if not re.fullmatch(r"[a-z0-9_]+", label) or not items:
            ap.error("--variant takes a label of lowercase letters, digits or _ and then KEY:VALUE items")
        variant = (label, parse_key_values(items, "--variant"))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    jobs = [{"cell": c, "algo": a, "reward": w, "trials": args.trials, "trial_steps": args.trial_steps,
             "seeds": args.seeds, "final_steps": args.final_steps or [None], "settings": args.settings,
             "variant": variant,
             "out": str(out)}
            for c in args.cells for a in args.learners for w in args.rewards if f"{c}:{a}:{w}" not in args.skip]
    # One torch and one XLA thread per process: several jobs never oversubscribe the cores.
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    if not args.report_only:
        # The studies first, then every final run (each seed its own job), ``--jobs`` at a time;
        # the slow learner's come first, so that the cores stay busy to the end.
        jobs.sort(key=lambda j: j["algo"] != "sac")
        with ProcessPoolExecutor(max_workers=args.jobs) as pool:
            for future in [pool.submit(_study, j) for j in jobs if "tuned" in j["settings"]]:
                future.result()
            for future in [pool.submit(_train, run) for j in jobs for run in _final_runs(j)]:
                future.result()
    # Every training run is tested on the same 20 episodes (seeds from TEST_SEED); so is the law.
    rows: list[dict[str, Any]] = []
    for cell in args.cells:
        rows += [_law(cell, 20)] + _rows(out, [cell])
    published = Path(args.publish or out) / "tune_learners.json"
    if published.exists():  # the published rows of runs that are not on this machine stay in the report
        rows = _merged(rows, json.loads(published.read_text()))
    table = _table(rows)
    for where in [out] + ([Path(args.publish)] if args.publish else []):
        where.mkdir(parents=True, exist_ok=True)
        (where / "tune_learners.json").write_text(json.dumps(rows, indent=1) + "\n")
        (where / "tune_learners.md").write_text(table)
        _plot(rows, where / "tune_learners.png")
        # The studies themselves (Optuna's SQLite storage, one per training reward): every trial can be
        # inspected (optuna-dashboard), and copied back to <out>/tuned/<reward>/ a study resumes elsewhere.
        for db in sorted((out / "tuned").glob("*/studies.db")) if where != out else ():
            (where / "studies").mkdir(exist_ok=True)
            shutil.copyfile(db, where / "studies" / f"{db.parent.name}.db")
    print(table)


if __name__ == "__main__":
    main()
