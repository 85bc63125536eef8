"""Where does learning beat the paper's law, and where not?  (issue 6)

Compares, on both environments and the scenarios nominal, saturated, mismatch, noisy and
coarse:

* ``geometric`` / ``geometric-sampled``: the paper's law (:class:`vnhc_gym.baselines.GeometricController`,
  the package's default gain ``DEFAULT_GAIN`` (5), ``variant="plain"`` / ``"sampled"``), no training;
* ``ppo``: PPO from scratch (``vnhc-gym train --algo ppo``);
* ``residual_ppo``: PPO acting through ``ResidualAction`` on top of the plain law
  (``vnhc-gym train --algo residual_ppo``).

Every learned cell (env, scenario, algo) is trained with ``--seeds`` seeds (default 5; seeds
0..4) for ``--steps`` env steps each, with the hyperparameters of ``agents/hyperparams/<env>.yml``,
trained *and* evaluated on that scenario.  During training the policy is evaluated every
``steps/10`` steps on 10 validation episodes (seeds 5000+, the learning curves) and the best
of those checkpoints (the untrained step-0 policy included) is kept.  Every policy is then
tested on ``--test-episodes`` held-out episodes (seeds 10000+, the same episodes for every
policy) with :func:`vnhc_gym.evaluation.evaluate`; the score of an episode is its mean ``|phi|``.

Aggregates (``final_table.md`` / ``.csv``): per cell the IQM of the pooled test scores (all
seeds x episodes; every seed is tested on the same episodes) with a 95 % percentile-bootstrap
CI that resamples training seeds and test episodes independently (for the deterministic
baselines: episodes only, which is the evaluation protocol's bootstrap).

Outputs in ``--out`` (default ``results/train_compare``): ``final_table.md``, ``final_table.csv``,
``runs.json`` (steps, wall time, throughput and test score of every run),
``learning_curves_<env>.png``, ``baselines.json``, and ``runs/<env>/<scenario>/<algo>/s<seed>/``
(model, sidecar, TensorBoard logs).  The script is resumable: finished runs (sidecar present,
trained on the same version of the environment code: ``code_fingerprint``) are skipped.
``--ship`` copies, for each env and algorithm, the model of the median seed on the
``--ship-scenario`` (default nominal) into ``vnhc_gym/agents_zoo/<env>-<algo>.zip`` with a JSON
sidecar recording its evaluation on 3 fixed episodes (seeds 10000..10002).

Usage::

    python experiments/train_compare.py --jobs 2            # the full comparison (~35 min on 2 cores)
    python experiments/train_compare.py --jobs 2 --ship     # ... and ship the median agents
    python experiments/train_compare.py --quick             # smoke test (~1-2 min)
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
import traceback
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import numpy as np

ENVS = ("flocking", "usv")
SCENARIOS = ("nominal", "saturated", "mismatch", "noisy", "coarse")
ALGOS = ("ppo", "residual_ppo")
VARIANTS = {"geometric": "plain", "geometric-sampled": "sampled"}
POLICY_ORDER = ("geometric", "geometric-sampled", "ppo", "residual_ppo")
FLOOR_SCENARIOS = ("mismatch", "coarse")
VALIDATION_SEED = 5_000
TEST_SEED = 10_000
ZOO_SEED = 10_000  #: shipped agents record their evaluation on episodes 10000, 10001, 10002
ZOO_EPISODES = 3
DEFAULT_STEPS = 50_000


# --------------------------------------------------------------------------- one training run (child process)
def _run_one(cfg: dict[str, Any]) -> dict[str, Any]:
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    os.environ.setdefault("MKL_NUM_THREADS", "1")
    from vnhc_gym.train import train

    t0 = time.perf_counter()
    try:
        side = train(cfg["env"], cfg["algo"], cfg["scenario"], cfg["seed"], n_timesteps=cfg["steps"],
                     output=cfg["dir"], eval_freq=cfg["eval_freq"], eval_episodes=cfg["eval_episodes"],
                     eval_seed=VALIDATION_SEED, test_episodes=cfg["test_episodes"], test_seed=TEST_SEED,
                     select="best", tensorboard=True, progress_bar=False, hyperparams=cfg.get("hyperparams"))
        return {"ok": True, "cfg": cfg, "wall": side["wall_time_s"], "iqm": side["final_eval"]["iqm"]}
    except Exception:  # noqa: BLE001 - reported by the parent, the run stays unfinished
        return {"ok": False, "cfg": cfg, "wall": time.perf_counter() - t0, "error": traceback.format_exc()}


def _run_dir(out: Path, env: str, scenario: str, algo: str, seed: int) -> Path:
    return out / "runs" / env / scenario / algo / f"s{seed}"


def _sidecar(d: Path, env: str, algo: str) -> Path:
    return d / f"{env}-{algo}.json"


#: Code fingerprint the finished runs must match (set in main; None accepts any).
CURRENT_FP: str | None = None


def _done(d: Path, env: str, algo: str) -> dict[str, Any] | None:
    p = _sidecar(d, env, algo)
    if not p.exists():
        return None
    try:
        side = json.loads(p.read_text())
    except ValueError:
        return None
    if not side.get("final_eval"):
        return None
    if CURRENT_FP is not None and side.get("code_fingerprint") != CURRENT_FP:
        return None  # trained on another version of the environments: stale, rerun
    return side


# --------------------------------------------------------------------------- baselines
def baseline_evals(out: Path, envs: list[str], scenarios: list[str], test_episodes: int, eval_episodes: int,
                   log: Any = print) -> dict[str, Any]:
    """Test (and validation) evaluations of both geometric variants; cached in ``baselines.json``."""
    from vnhc_gym.baselines import GeometricController
    from vnhc_gym.baselines.geometric import DEFAULT_GAIN
    from vnhc_gym.train import ENV_ALIASES, evaluate_policy_protocol

    path = out / "baselines.json"
    cache: dict[str, Any] = json.loads(path.read_text()) if path.exists() else {}
    for env in envs:
        for scenario in scenarios:
            for name, variant in VARIANTS.items():
                key = f"{env}/{scenario}/{name}"
                c = cache.get(key)
                if (c and c["test"]["n_episodes"] == test_episodes and c["validation"]["n_episodes"] == eval_episodes
                        and (CURRENT_FP is None or c.get("code_fingerprint") == CURRENT_FP)):
                    continue

                def make(e: Any, v: str = variant) -> Any:
                    return GeometricController(e, gain=DEFAULT_GAIN, variant=v)

                t = time.perf_counter()
                test = evaluate_policy_protocol(make, ENV_ALIASES[env], scenario, test_episodes, TEST_SEED)
                val = evaluate_policy_protocol(make, ENV_ALIASES[env], scenario, eval_episodes, VALIDATION_SEED)
                cache[key] = {"env": env, "scenario": scenario, "policy": name, "variant": variant,
                              "gain": DEFAULT_GAIN, "code_fingerprint": CURRENT_FP,
                              "test": test, "validation": val, "wall_s": round(time.perf_counter() - t, 2)}
                log(f"[baseline] {key}: test IQM {test['iqm']:.4g} [{test['ci_low']:.4g}, {test['ci_high']:.4g}]")
                path.write_text(json.dumps(cache, indent=1))
    return cache


# --------------------------------------------------------------------------- aggregation
def iqm_of(x: Any) -> float:
    from vnhc_gym.train import iqm_of as _iqm

    return _iqm(np.asarray(x, dtype=np.float64))


def crossed_bootstrap_ci(scores: np.ndarray, n_boot: int = 2000, seed: int = 0,
                         level: float = 0.95) -> tuple[float, float]:
    """Percentile CI of the IQM of a ``(runs, episodes)`` score matrix whose columns are the *same*
    test episodes for every run: each resample draws runs and episodes (columns) with
    replacement, independently, and takes the IQM of the selected block.  With one run it is
    the ordinary bootstrap over episodes (as for the baselines)."""
    from scipy import stats

    x = np.asarray(scores, dtype=np.float64)
    rng = np.random.default_rng(seed)
    n_r, n_e = x.shape
    vals = np.empty(n_boot)
    for b in range(n_boot):
        rows = rng.integers(n_r, size=n_r)
        cols = rng.integers(n_e, size=n_e)
        vals[b] = stats.trim_mean(x[np.ix_(rows, cols)].ravel(), 0.25)
    a = (1.0 - level) / 2.0
    return float(np.quantile(vals, a)), float(np.quantile(vals, 1.0 - a))


def _cell_stats(groups: list[list[float]]) -> dict[str, Any]:
    from vnhc_gym.train import iqm_of

    mat = np.asarray(groups, dtype=np.float64).reshape(len(groups), -1)
    pooled = mat.ravel()
    lo, hi = crossed_bootstrap_ci(mat) if pooled.size else (float("nan"), float("nan"))
    return {"iqm": iqm_of(pooled), "ci_low": lo, "ci_high": hi, "mean": float(np.mean(pooled)) if pooled.size else
            float("nan"), "n_runs": len(groups), "n_episodes": int(pooled.size)}


def _fmt(s: dict[str, Any]) -> str:
    if not s or not np.isfinite(s.get("iqm", np.nan)):
        return "n/a"
    return f"{s['iqm']:.3g} [{s['ci_low']:.3g}, {s['ci_high']:.3g}]"


def aggregate(out: Path, envs: list[str], scenarios: list[str], algos: list[str], seeds: list[int],
              baselines: dict[str, Any], settings: dict[str, Any]) -> dict[str, Any]:
    """Write final_table.md/.csv and runs.json from the finished runs; returns the cell table."""
    cells: dict[tuple[str, str, str], dict[str, Any]] = {}
    runs: list[dict[str, Any]] = []
    for env in envs:
        for scenario in scenarios:
            for name in VARIANTS:
                b = baselines.get(f"{env}/{scenario}/{name}")
                if b:
                    cells[(env, scenario, name)] = {**_cell_stats([b["test"]["episodes"]]), "steps": 0,
                                                    "wall_s": b["wall_s"], "per_seed_iqm": [b["test"]["iqm"]]}
            for algo in algos:
                groups, steps, walls, per_seed, last_groups, n_step0 = [], [], [], [], [], 0
                for seed in seeds:
                    side = _done(_run_dir(out, env, scenario, algo, seed), env, algo)
                    if side is None:
                        continue
                    fe = side["final_eval"]
                    groups.append(fe["episodes"])
                    steps.append(side["steps"])
                    walls.append(side["wall_time_s"])
                    per_seed.append(fe["iqm"])
                    if side.get("last_eval"):
                        last_groups.append(side["last_eval"]["episodes"])
                    n_step0 += int(side["selected"] == "best" and side["selected_step"] == 0)
                    runs.append({"env": env, "scenario": scenario, "algo": algo, "seed": seed, "steps": side["steps"],
                                 "wall_time_s": side["wall_time_s"], "learn_time_s": side["learn_time_s"],
                                 "eval_time_s": side["eval_time_s"], "steps_per_s": side["steps_per_s"],
                                 "selected": side["selected"], "selected_step": side["selected_step"],
                                 "test_iqm": fe["iqm"], "test_ci": [fe["ci_low"], fe["ci_high"]],
                                 "last_test_iqm": (side.get("last_eval") or {}).get("iqm")})
                if groups:
                    cells[(env, scenario, algo)] = {**_cell_stats(groups), "steps": int(np.median(steps)),
                                                    "wall_s": float(np.mean(walls)), "per_seed_iqm": per_seed,
                                                    "n_step0": n_step0}
                if last_groups:
                    cells[(env, scenario, f"{algo}@last")] = {**_cell_stats(last_groups),
                                                              "steps": int(np.median(steps)),
                                                              "wall_s": float(np.mean(walls)),
                                                              "per_seed_iqm": [iqm_of(g) for g in last_groups]}
    # CSV
    import csv

    rows = []
    for (env, scenario, policy), s in cells.items():
        rows.append({"env": env, "scenario": scenario, "policy": policy, "iqm_mean_abs_phi": s["iqm"],
                     "ci_low": s["ci_low"], "ci_high": s["ci_high"], "mean": s["mean"], "n_runs": s["n_runs"],
                     "n_episodes": s["n_episodes"], "train_steps": s["steps"], "mean_wall_time_s": s["wall_s"],
                     "per_seed_iqm": " ".join(f"{v:.4g}" for v in s["per_seed_iqm"])})
    with open(out / "final_table.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]) if rows else ["env"])
        w.writeheader()
        w.writerows(rows)
    # floor check
    floor = []
    for env in envs:
        for scenario in FLOOR_SCENARIOS:
            r = cells.get((env, scenario, "residual_ppo"))
            if r is None or scenario not in scenarios:
                continue
            for name in VARIANTS:
                b = cells.get((env, scenario, name))
                if b is None:
                    continue
                point = r["iqm"] <= b["iqm"] * (1 + 1e-9)  # equal up to rounding counts as "at most"
                ci_against = b["ci_high"] < r["ci_low"]  # the CIs favour the baseline
                floor.append({"env": env, "scenario": scenario, "baseline": name, "residual_iqm": r["iqm"],
                              "baseline_iqm": b["iqm"], "residual_le_baseline": bool(point),
                              "cis_favour_baseline": bool(ci_against), "holds": bool(point and not ci_against)})
    # Markdown
    md = ["# Learning vs the geometric law: mean |phi| on held-out episodes", "",
          f"IQM [95% CI] of the per-episode mean |phi| (flocking: m^2/s^2, USV: m/s; lower is better) on "
          f"{settings['test_episodes']} held-out test episodes "
          f"(seeds {TEST_SEED}..{TEST_SEED + settings['test_episodes'] - 1}, "
          f"{settings['max_time']:g} s each). Learned cells pool {len(seeds)} training seeds x "
          f"{settings['test_episodes']} episodes (the same episodes for every seed); the CI is a percentile bootstrap "
          "that resamples training seeds and test episodes independently (baselines: episodes). "
          "Each learned cell is trained and tested on its scenario for "
          f"{settings['steps']} env steps per run (best of {settings['n_evals']} validation checkpoints on seeds "
          f"{VALIDATION_SEED}+, including step 0). geometric = paper's law (gain {settings['gain']:g}) held over the "
          "control period; "
          "geometric-sampled = its zero-order-hold-exact variant; residual_ppo = PPO residual (scale 0.2) on top of "
          "geometric.", ""]
    for env in envs:
        md += [f"## {env}", "", "| scenario | " + " | ".join(POLICY_ORDER) + " |",
               "|---|" + "---|" * len(POLICY_ORDER)]
        for scenario in scenarios:
            md.append(f"| {scenario} | " + " | ".join(_fmt(cells.get((env, scenario, p), {})) for p in POLICY_ORDER)
                      + " |")
        md.append("")
    learned = [a for a in algos if any((env, sc, f"{a}@last") in cells for env in envs for sc in scenarios)]
    if learned:
        md += ["## Without checkpoint selection", "",
               "The tables above use, for every run, the best of the validation checkpoints (seeds "
               f"{VALIDATION_SEED}+, never the test episodes), the untrained policy at step 0 included: for "
               "residual PPO that is exactly the geometric law (its residual network starts at zero). Here the "
               "*last* policy of every run instead, on the same test episodes; `step-0 kept` counts the runs whose "
               "selected checkpoint was step 0 (learning did not beat the law on validation).", ""]
        head = [f"{a} (last)" for a in learned] + [f"{a}: step-0 kept" for a in learned]
        for env in envs:
            md += [f"**{env}**", "", "| scenario | " + " | ".join(head) + " |", "|---|" + "---|" * len(head)]
            for scenario in scenarios:
                cl = [_fmt(cells.get((env, scenario, f"{a}@last"), {})) for a in learned]
                k0 = [f"{cells[(env, scenario, a)]['n_step0']}/{cells[(env, scenario, a)]['n_runs']}"
                      if (env, scenario, a) in cells else "n/a" for a in learned]
                md.append(f"| {scenario} | " + " | ".join(cl + k0) + " |")
            md.append("")
    if floor:
        md += ["## Floor: residual PPO vs the geometric law on mismatch and coarse", "",
               "Holds when residual PPO's IQM is at most the baseline's and the 95% CIs do not favour the "
               "baseline (baseline's upper bound below residual's lower bound).", "",
               "| env | scenario | baseline | residual IQM | baseline IQM | residual <= baseline "
               "| CIs favour baseline | holds |",
               "|---|---|---|---|---|---|---|---|"]
        for f in floor:
            md.append(f"| {f['env']} | {f['scenario']} | {f['baseline']} | {f['residual_iqm']:.4g} | "
                      f"{f['baseline_iqm']:.4g} | {f['residual_le_baseline']} | {f['cis_favour_baseline']} | "
                      f"{'yes' if f['holds'] else 'NO'} |")
        md.append("")
    if runs:
        walls = [r["wall_time_s"] for r in runs]
        md += ["## Cost", "", f"{len(runs)} runs, {settings['steps']} env steps each; wall time per run "
               f"(1 process, 1 torch thread, {settings['jobs']} runs in parallel on a 2-core machine): "
               f"median {np.median(walls):.0f} s, max {np.max(walls):.0f} s, total {np.sum(walls) / 60:.1f} "
               "min of process time. Per-run numbers in runs.json.", ""]
        md += ["| env | algo | median wall time per run (s) | median throughput (steps/s, training only) |",
               "|---|---|---|---|"]
        for env in envs:
            for algo in algos:
                rr = [r for r in runs if r["env"] == env and r["algo"] == algo]
                if rr:
                    md.append(f"| {env} | {algo} | {np.median([r['wall_time_s'] for r in rr]):.0f} | "
                              f"{np.median([r['steps_per_s'] for r in rr]):.0f} |")
        md.append("")
    if settings.get("command"):
        md += [f"Command: `{settings['command']}`", ""]
    (out / "final_table.md").write_text("\n".join(md))
    (out / "runs.json").write_text(json.dumps({"settings": settings, "runs": runs, "floor": floor}, indent=1))
    return {"cells": cells, "floor": floor, "runs": runs}


# --------------------------------------------------------------------------- figures
def learning_curves(out: Path, envs: list[str], scenarios: list[str], algos: list[str], seeds: list[int],
                    baselines: dict[str, Any]) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []
    colors = {"ppo": "C0", "residual_ppo": "C3", "geometric": "k", "geometric-sampled": "0.5"}
    for env in envs:
        fig, axes = plt.subplots(1, len(scenarios), figsize=(3.6 * len(scenarios), 3.4), squeeze=False)
        for ax, scenario in zip(axes[0], scenarios, strict=True):
            for algo in algos:
                curves = []
                for seed in seeds:
                    side = _done(_run_dir(out, env, scenario, algo, seed), env, algo)
                    if side is None:
                        continue
                    c = side["validation"]["curve"]
                    x = np.array([p["step"] for p in c], dtype=float)
                    y = np.array([p["iqm"] for p in c], dtype=float)
                    ax.plot(x, y, color=colors[algo], alpha=0.25, lw=0.8)
                    curves.append((x, y))
                if curves:
                    n = min(len(c[0]) for c in curves)
                    x = curves[0][0][:n]
                    ys = np.stack([c[1][:n] for c in curves])
                    ax.plot(x, np.median(ys, axis=0), color=colors[algo], lw=2,
                            label=f"{algo} (median of {len(curves)})")
            for name, ls in (("geometric", "--"), ("geometric-sampled", ":")):
                b = baselines.get(f"{env}/{scenario}/{name}")
                if b:
                    ax.axhline(b["validation"]["iqm"], color=colors[name], ls=ls, lw=1.2, label=name)
            ax.set_yscale("log")
            ax.set_title(scenario)
            ax.set_xlabel("env steps")
            ax.grid(True, which="both", alpha=0.25)
        axes[0, 0].set_ylabel("validation IQM mean |phi|")
        handles, labels = axes[0, 0].get_legend_handles_labels()
        fig.legend(handles, labels, loc="lower center", ncol=4, frameon=False)
        unit = "m²/s²" if env == "flocking" else "m/s"
        fig.suptitle(f"{env}: IQM of mean |phi| ({unit}) on 10 validation episodes (seeds {VALIDATION_SEED}+) "
                     "during training")
        fig.tight_layout(rect=(0, 0.09, 1, 0.95))
        p = out / f"learning_curves_{env}.png"
        fig.savefig(p, dpi=100)
        plt.close(fig)
        paths.append(p)
    return paths


# --------------------------------------------------------------------------- shipping
def ship(out: Path, envs: list[str], algos: list[str], seeds: list[int], scenario: str, zoo: Path,
         log: Any = print) -> list[Path]:
    """Copy the median-seed model of each (env, algo) trained on ``scenario`` into the zoo."""
    from vnhc_gym.train import evaluate_policy_protocol, load_agent

    zoo.mkdir(parents=True, exist_ok=True)
    shipped = []
    for env in envs:
        for algo in algos:
            done = []
            for seed in seeds:
                d = _run_dir(out, env, scenario, algo, seed)
                side = _done(d, env, algo)
                if side is not None:
                    done.append((side["final_eval"]["iqm"], seed, d, side))
            if not done:
                log(f"[ship] {env}-{algo}: no finished run on {scenario}; skipped")
                continue
            done.sort(key=lambda t: (t[0], t[1]))
            iqm, seed, d, side = done[(len(done) - 1) // 2]  # the median (lower median for even counts)
            stem = f"{env}-{algo}"
            if side.get("obs_normalization"):
                log(f"[ship] {stem}: trained with observation normalisation; `vnhc-gym benchmark` feeds raw "
                    "observations to shipped models, so it is not shipped")
                continue
            dst = zoo / f"{stem}.zip"
            shutil.copyfile(d / f"{stem}.zip", dst)
            agent = load_agent(stem)  # from the zoo now
            ev = evaluate_policy_protocol(agent, agent.env_id, scenario, ZOO_EPISODES, ZOO_SEED)
            meta = {k: side[k] for k in ("format", "env_id", "env_short", "scenario", "algo", "method", "seed",
                                         "residual", "env_kwargs", "n_timesteps", "steps", "wall_time_s",
                                         "hyperparams", "selected", "selected_step", "versions", "created")}
            if meta["residual"]:
                meta["residual"] = {**meta["residual"], "gain": meta["residual"].get("gain", 1.0)}
            meta.update(
                name=stem, obs_normalization=None, files={"model": dst.name, "vecnormalize": None},
                description=(f"{algo} trained on {env} / {scenario} for {side['steps']} steps; the median of "
                             f"{len(done)} training seeds by test IQM (experiments/train_compare.py)."),
                final_eval=side["final_eval"],
                zoo_eval={"scenario": scenario, "seed": ZOO_SEED, "n_episodes": ZOO_EPISODES, "deterministic": True,
                          "episodes": ev["episodes"], "iqm": ev["iqm"], "mean": ev["mean"]},
            )
            (zoo / f"{stem}.json").write_text(json.dumps(meta, indent=1))
            log(f"[ship] {dst} (seed {seed}, test IQM {iqm:.4g}; {dst.stat().st_size / 1024:.0f} KB)")
            shipped.append(dst)
    return shipped


# --------------------------------------------------------------------------- main
def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, default=None, help="output folder (default results/train_compare, "
                   "--quick: results/train_compare_quick)")
    p.add_argument("--envs", nargs="+", choices=ENVS, default=list(ENVS))
    p.add_argument("--scenarios", nargs="+", choices=SCENARIOS, default=None)
    p.add_argument("--algos", nargs="+", choices=ALGOS, default=list(ALGOS))
    p.add_argument("--seeds", type=int, default=None, help="training seeds 0..N-1 (default 5; --quick 2)")
    p.add_argument("--steps", type=int, default=None, help=f"env steps per run (default {DEFAULT_STEPS}; --quick 2048)")
    p.add_argument("--test-episodes", type=int, default=None, help="held-out test episodes (default 20; --quick 3)")
    p.add_argument("--eval-episodes", type=int, default=None, help="validation episodes (default 10; --quick 2)")
    p.add_argument("--n-evals", type=int, default=5, help="validation evaluations per run (besides step 0)")
    p.add_argument("--jobs", type=int, default=1, help="trainings in parallel processes")
    p.add_argument("--quick", action="store_true", help="smoke test: 2048 steps, 2 seeds, nominal + coarse")
    p.add_argument("--ship", action="store_true", help="copy the median agents into vnhc_gym/agents_zoo")
    p.add_argument("--ship-scenario", default="nominal")
    p.add_argument("--zoo", type=Path, default=None, help="zoo folder for --ship (default vnhc_gym/agents_zoo)")
    p.add_argument("--no-train", action="store_true", help="only aggregate / plot / ship finished runs")
    p.add_argument("--accept-stale", action="store_true", help="count runs trained on another version of the "
                   "environment code (by default they are retrained: sidecar code_fingerprint)")
    args = p.parse_args(argv)

    quick = args.quick
    out = args.out or Path("results/train_compare_quick" if quick else "results/train_compare")
    scenarios = args.scenarios or (["nominal", "coarse"] if quick else list(SCENARIOS))
    n_seeds = args.seeds or (2 if quick else 5)
    seeds = list(range(n_seeds))
    steps = args.steps or (2048 if quick else DEFAULT_STEPS)
    test_episodes = args.test_episodes or (3 if quick else 20)
    eval_episodes = args.eval_episodes or (2 if quick else 10)
    eval_freq = max(steps // max(args.n_evals, 1), 1)
    out.mkdir(parents=True, exist_ok=True)
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
        os.environ.setdefault(var, "1")

    def log(msg: str) -> None:
        print(f"{time.strftime('%H:%M:%S')} {msg}", flush=True)

    global CURRENT_FP
    from vnhc_gym.train import code_fingerprint

    CURRENT_FP = None if args.accept_stale else code_fingerprint()
    import vnhc_gym  # noqa: F401

    t0 = time.perf_counter()
    from vnhc_gym.baselines.geometric import DEFAULT_GAIN

    settings = {"gain": DEFAULT_GAIN, "envs": args.envs, "scenarios": scenarios, "algos": args.algos, "seeds": seeds,
                "steps": steps,
                "test_episodes": test_episodes, "eval_episodes": eval_episodes, "n_evals": args.n_evals,
                "eval_freq": eval_freq, "jobs": args.jobs, "max_time": 20.0, "quick": quick,
                "command": "python experiments/train_compare.py " + " ".join(sys.argv[1:] if argv is None else argv)}
    baselines = baseline_evals(out, args.envs, scenarios, test_episodes, eval_episodes, log=log)

    if not args.no_train:
        todo = []
        for seed in seeds:  # seed-major order: every cell gets its first seeds early
            for env in args.envs:
                for scenario in scenarios:
                    for algo in args.algos:
                        d = _run_dir(out, env, scenario, algo, seed)
                        if _done(d, env, algo) is not None:
                            continue
                        todo.append({"env": env, "scenario": scenario, "algo": algo, "seed": seed, "dir": str(d),
                                     "steps": steps, "eval_freq": eval_freq, "eval_episodes": eval_episodes,
                                     "test_episodes": test_episodes})
        n_total = len(seeds) * len(args.envs) * len(scenarios) * len(args.algos)
        log(f"{n_total - len(todo)} of {n_total} runs already finished; {len(todo)} to go with {args.jobs} job(s)")
        failed = 0
        finished = 0
        t_train = time.perf_counter()
        with ProcessPoolExecutor(max_workers=max(args.jobs, 1), mp_context=get_context("spawn"),
                                 max_tasks_per_child=1) as pool:
            pending: set[Future[dict[str, Any]]] = {pool.submit(_run_one, cfg) for cfg in todo}
            while pending:
                done, pending = wait(pending, return_when=FIRST_COMPLETED)
                for fut in done:
                    r = fut.result()
                    c = r["cfg"]
                    finished += 1
                    tag = f"{c['env']}/{c['scenario']}/{c['algo']}/s{c['seed']}"
                    if r["ok"]:
                        el = time.perf_counter() - t_train
                        eta = el / finished * (len(todo) - finished)
                        log(f"[{finished}/{len(todo)}] {tag}: test IQM {r['iqm']:.4g}, {r['wall']:.0f} s "
                            f"(elapsed {el / 60:.1f} min, ETA {eta / 60:.1f} min)")
                    else:
                        failed += 1
                        log(f"[{finished}/{len(todo)}] {tag} FAILED:\n{r['error']}")
        if failed:
            log(f"{failed} run(s) failed; rerun the same command to retry them")

    settings["wall_time_total_s"] = round(time.perf_counter() - t0, 1)
    settings["code_fingerprint"] = CURRENT_FP
    if CURRENT_FP is not None and code_fingerprint() != CURRENT_FP:
        log("WARNING: the environment code changed while this ran; rerun the same command to retrain stale runs")
    res = aggregate(out, args.envs, scenarios, args.algos, seeds, baselines, settings)
    figs = learning_curves(out, args.envs, scenarios, args.algos, seeds, baselines)
    log(f"wrote {out / 'final_table.md'}, {out / 'final_table.csv'}, {out / 'runs.json'}, "
        + ", ".join(str(f) for f in figs))
    for f in res["floor"]:
        log(f"[floor] {f['env']}/{f['scenario']} vs {f['baseline']}: residual {f['residual_iqm']:.4g} vs "
            f"{f['baseline_iqm']:.4g} -> {'holds' if f['holds'] else 'FAILS'}")
    if args.ship:
        from vnhc_gym.train import ZOO_DIR

        ship(out, args.envs, args.algos, seeds, args.ship_scenario, args.zoo or ZOO_DIR, log=log)
    print((out / "final_table.md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
