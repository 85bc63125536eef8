"""A grid of training-and-evaluation runs, on one machine or a Ray cluster, resumable, and its report.

A run is one `RunSpec`: a learned agent (``ppo``, ``residual_ppo``, ``ppo_history``, ``sac``,
``residual_sac``) trained and tested, a classical baseline (``law``, ``tuned_law``, ``safe_law``,
``observer``, ``kalman``, ``adaptive``, ``mpc``) tuned on validation episodes and tested, or the
headroom reference ``oracle`` (the sampled-data law on the true state and parameters), tuned and
tested the same way.  Every choice
(settings, checkpoints, the best classical baseline of a cell) and every table ranks on the
``score`` (the return over the fixed horizon per step, failed episodes' remaining steps counting
0), higher is better.

A run's outputs go to ``<out>/runs/<stem>.*`` under a stable name derived from its configuration,
with the sidecar (``<stem>.json``) written last: a run with a sidecar is finished.  Rerunning the
same grid skips finished runs, reruns failed or partial ones, and [`report`][vnhc_gym.sweep.report] warns when finished
runs come from different code versions.

Executors: ``local`` (an in-process loop, or ``jobs`` worker processes) and ``ray`` (one Ray task
per run with its CPUs declared, retried ``retries`` times, then recorded as failed with its
traceback; a local Ray instance by default, a cluster with ``address``).  Both run the same
`run_one`, so they give the same numbers for the same seeds.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import time
import traceback
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["CLASSICAL_ALGOS", "LEARNED_ALGOS", "PLANNING_ALGOS", "REFERENCE_ALGOS", "RESIDUAL_ALGOS", "RunSpec",
           "grid", "load_runs", "report", "restore_records", "run_one", "run_sweep", "save_records", "status"]

#: Learned agents (trained with vnhc_gym.training), classical baselines (vnhc_gym.baselines.tuning)
#: and the headroom reference (not a controller one could field: never a cell's best classical).
LEARNED_ALGOS = ("ppo", "residual_ppo", "ppo_history", "sac", "residual_sac")
#: Learned agents that correct a classical base (the cell's best classical baseline).
RESIDUAL_ALGOS = ("residual_ppo", "residual_sac")
CLASSICAL_ALGOS = ("law", "tuned_law", "safe_law", "observer", "kalman", "adaptive", "mpc")
#: Classical baselines that plan (model-predictive control): fielded as they are, never a residual base.
PLANNING_ALGOS = ("mpc",)
REFERENCE_ALGOS = ("oracle",)
ALL_ALGOS = LEARNED_ALGOS + CLASSICAL_ALGOS + REFERENCE_ALGOS
#: The metric of every choice and table (its mean over episodes), higher is better.
SCORE = "score"



@dataclass(frozen=True)
class RunSpec:
    """One run of a sweep: what to train or tune, where, with which seed and budget."""

    algo: str
    env: str
    scenario: str = "nominal"
    seed: int = 0
    n_timesteps: int = 1_000_000
    overrides: tuple[tuple[str, Any], ...] = ()  #: hyperparameter overrides, as sorted pairs
    test_episodes: int = 20
    eval_episodes: int = 10
    #: A residual agent's candidate bases (its cell's best of them is its base); empty: every
    #: classical baseline but the planner.
    bases: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.algo not in ALL_ALGOS:
            raise ValueError(f"algo must be one of {list(ALL_ALGOS)}, got {self.algo!r}")
        object.__setattr__(self, "bases", tuple(self.bases))
        bad = [b for b in self.bases if b not in CLASSICAL_ALGOS or b in PLANNING_ALGOS]
        if bad:
            raise ValueError(f"bases must be classical baselines other than the planner, got {bad}")

    @property
    def learned(self) -> bool:
        return self.algo in LEARNED_ALGOS

    def key(self) -> str:
        """A hash of the configuration (classical runs ignore the budget)."""
        d = asdict(self)
        if not self.bases:
            d.pop("bases")  # (the default: keys of runs that name no bases stay as they were)
        if not self.learned:
            d.pop("n_timesteps")
            d.pop("seed")
        return hashlib.sha256(json.dumps(d, sort_keys=True, default=str).encode()).hexdigest()[:10]

    @property
    def stem(self) -> str:
        seed = f"-s{self.seed}" if self.learned else ""
        return f"{self.env}-{self.scenario}-{self.algo}{seed}-{self.key()}"


def grid(envs: Sequence[str], scenarios: Sequence[str], algos: Sequence[str], seeds: Sequence[int],
         n_timesteps: int, *, overrides: dict[str, Any] | None = None, test_episodes: int = 20,
         eval_episodes: int = 10, seeds_by_scenario: dict[str, Sequence[int]] | None = None) -> list[RunSpec]:
    """Every combination; classical baselines get one run per cell (they are deterministic).  A
    residual agent's base is the best of the grid's own classical baselines of its cell (all of them
    but the planner when the grid has none)."""
    ov = tuple(sorted((overrides or {}).items()))
    bases = tuple(a for a in algos if a in CLASSICAL_ALGOS and a not in PLANNING_ALGOS)
    out = []
    for env in envs:
        for scenario in scenarios:
            cell_seeds = list((seeds_by_scenario or {}).get(scenario, seeds))
            for algo in algos:
                for seed in (cell_seeds if algo in LEARNED_ALGOS else cell_seeds[:1]):
                    out.append(RunSpec(algo, env, scenario, int(seed), int(n_timesteps), ov, test_episodes,
                                       eval_episodes, bases if algo in RESIDUAL_ALGOS else ()))
    return out


def status(spec: RunSpec, out: str | Path) -> str:
    """``"done"`` (a sidecar exists), ``"failed"`` (an error file exists) or ``"todo"``."""
    runs = Path(out) / "runs"
    if (runs / f"{spec.stem}.json").exists():
        return "done"
    if (runs / f"{spec.stem}.error").exists():
        return "failed"
    return "todo"


def _atomic_json(path: Path, data: Any) -> None:
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(data, indent=1))
    os.replace(tmp, path)


def run_one(spec: RunSpec, out: str | Path, threads: int = 1, packages: Sequence[str] = ()) -> dict[str, Any]:
    """Do one run and write its outputs (the sidecar last); returns the sidecar.

    ``packages`` are imported first (``--gym-packages``: the modules that register a user's tasks,
    needed again in a worker process).
    """
    from vnhc_gym.cli import import_gym_packages

    import_gym_packages(packages)
    runs = Path(out) / "runs"
    runs.mkdir(parents=True, exist_ok=True)
    (runs / f"{spec.stem}.error").unlink(missing_ok=True)
    import vnhc_gym
    from vnhc_gym.training.run import code_fingerprint, resolve_env_id

    env_id = resolve_env_id(spec.env)
    t0 = time.perf_counter()
    if spec.learned:
        from vnhc_gym.training import TrainConfig, train

        algo = "ppo" if spec.algo == "ppo_history" else spec.algo
        overrides = dict(spec.overrides)
        if spec.algo == "ppo_history":
            overrides.setdefault("frame_stack", 4)
        base, settings = _best_classical(spec, out, env_id) if algo in RESIDUAL_ALGOS else (None, None)
        cfg = TrainConfig(algo=algo, env=spec.env, scenario=spec.scenario, seed=spec.seed,
                          n_timesteps=spec.n_timesteps, out=str(runs), threads=threads, name=spec.stem,
                          eval_episodes=spec.eval_episodes, test_episodes=spec.test_episodes, overrides=overrides,
                          residual_base=base, residual_base_settings=settings)
        meta = train(cfg)
        meta["sweep_algo"] = spec.algo
    else:
        from vnhc_gym.baselines.tuning import evaluate_classical, tune
        from vnhc_gym.evaluation import TEST_SEED

        best, table = tune(spec.algo, env_id, spec.scenario, n_episodes=spec.eval_episodes)
        if not table:  # the baseline cannot act in this cell (a safety filter without velocity limits)
            meta = {"name": spec.stem, "algo": spec.algo, "sweep_algo": spec.algo, "env_id": env_id,
                    "scenario": spec.scenario, "skipped": f"{spec.algo} cannot act on {env_id}", "test": None,
                    "version": vnhc_gym.__version__, "code": code_fingerprint(), "spec": asdict(spec),
                    "run_wall": time.perf_counter() - t0}
            _atomic_json(runs / f"{spec.stem}.json", meta)
            return meta
        built: list[Any] = []
        test = evaluate_classical(spec.algo, best, env_id, spec.scenario, spec.test_episodes, TEST_SEED, built=built)
        meta = {"name": spec.stem, "algo": spec.algo, "sweep_algo": spec.algo, "env_id": env_id,
                "scenario": spec.scenario, "settings": best, "tuning": table,
                "validation_score": max(row["score"] for row in table),
                "test": {k: v for k, v in test.to_dict().items() if k in ("metrics", "summary", "seed", "n_episodes")},
                "version": vnhc_gym.__version__, "code": code_fingerprint()}
        solves = sum(getattr(p, "n_solves", 0) for p in built)
        if solves:  # a planning baseline: its solve time per control step (for a batch of test episodes)
            meta["solve_seconds_per_step"] = sum(p.solve_seconds for p in built) / solves
    meta["spec"] = asdict(spec)
    meta["run_wall"] = time.perf_counter() - t0
    _atomic_json(runs / f"{spec.stem}.json", meta)
    return meta


def _best_classical(spec: RunSpec, out: str | Path, env_id: str) -> tuple[str, dict[str, Any]]:
    """The best of the run's candidate bases (``spec.bases``) in its cell (highest validation score)
    and its settings: the
    base of a residual agent, which then starts from the strongest model-based controller of the cell.
    Read from the cell's finished classical runs when they are all there, else tuned here (on
    validation episodes, as they would be).  The planning baseline is never a base: it plans at
    every step of every training environment, which would make training hundreds of times slower."""
    candidates = spec.bases or tuple(a for a in CLASSICAL_ALGOS if a not in PLANNING_ALGOS)
    # The grid gives its classical runs the overrides it gives every run: the same stems, so found.
    cell = [RunSpec(a, spec.env, spec.scenario, overrides=spec.overrides, test_episodes=spec.test_episodes,
                    eval_episodes=spec.eval_episodes) for a in candidates]
    found = [Path(out) / "runs" / f"{c.stem}.json" for c in cell]
    if all(f.exists() for f in found):
        runs = [r for r in (json.loads(f.read_text()) for f in found) if not r.get("skipped")]
        best = max(runs, key=lambda r: r["validation_score"])
        return str(best["algo"]), dict(best["settings"])
    from vnhc_gym.baselines.tuning import tune

    scored = []
    for c in cell:
        settings, table = tune(c.algo, env_id, spec.scenario, n_episodes=spec.eval_episodes)
        if table:  # (empty: the baseline cannot act in this cell)
            scored.append((max(row["score"] for row in table), c.algo, settings))
    _, name, settings = max(scored, key=lambda t: t[0])
    return name, settings


def _guarded(spec: RunSpec, out: str, threads: int, packages: Sequence[str] = ()) -> tuple[str, str | None]:
    """`run_one` that records a failure (with its traceback) instead of raising."""
    try:
        run_one(spec, out, threads, packages)
        return spec.stem, None
    except Exception:  # noqa: BLE001 - a failed run is recorded, the sweep goes on
        tb = traceback.format_exc()
        err = Path(out) / "runs" / f"{spec.stem}.error"
        err.parent.mkdir(parents=True, exist_ok=True)
        err.write_text(tb)
        return spec.stem, tb


def _progress(done: int, failed: int, running: int, total: int, t0: float, log: Callable[[str], None]) -> None:
    finished = done + failed
    eta = (time.perf_counter() - t0) / finished * (total - finished) if finished else float("nan")
    log(f"sweep: {done} done, {running} running, {failed} failed of {total}"
        + (f"; about {eta / 60:.0f} min left" if np.isfinite(eta) else ""))


def run_sweep(specs: Iterable[RunSpec], out: str | Path, *, executor: str = "local", jobs: int = 1, threads: int = 1,
              address: str | None = None, retries: int = 2, rerun_failed: bool = True,
              log: Callable[[str], None] = print, packages: Sequence[str] = ()) -> dict[str, list[str]]:
    """Run every unfinished spec; returns ``{"done": [...], "failed": [...], "skipped": [...]}``.

    ``executor="local"`` runs in this process (``jobs=1``) or in ``jobs`` worker processes;
    ``"ray"`` submits one task per run to Ray (``address``: an existing cluster, else a local
    instance; ``RAY_ADDRESS`` works too).  Ctrl-C stops the sweep; finished runs stay.  ``packages``:
    modules every run imports first (``--gym-packages``).
    """
    out = str(out)
    specs = list(specs)
    todo = [s for s in specs if status(s, out) == "todo" or (rerun_failed and status(s, out) == "failed")]
    skipped = [s.stem for s in specs if s not in todo]
    result: dict[str, list[str]] = {"done": [], "failed": [], "skipped": skipped}
    log(f"sweep: {len(specs)} runs, {len(skipped)} already finished, {len(todo)} to do ({executor})")
    t0 = time.perf_counter()
    if not todo:
        return result
    if executor == "ray":
        return _run_ray(todo, out, threads, address, retries, result, log, t0, packages)
    if executor != "local":
        raise ValueError(f"executor must be 'local' or 'ray', got {executor!r}")
    if jobs <= 1:
        for spec in todo:
            _progress(len(result["done"]), len(result["failed"]), 1, len(todo), t0, log)
            stem, err = _guarded(spec, out, threads, packages)
            result["failed" if err else "done"].append(stem)
            if err:
                log(f"sweep: {stem} failed:\n{err.strip().splitlines()[-1]}")
        return result
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        futures = {pool.submit(_guarded, s, out, threads, packages): s for s in todo}
        for fut in as_completed(futures):
            stem, err = fut.result()
            result["failed" if err else "done"].append(stem)
            finished = len(result["done"]) + len(result["failed"])
            _progress(len(result["done"]), len(result["failed"]), min(jobs, len(todo) - finished), len(todo), t0, log)
    return result


#: Runs that compute on JAX's default device (SBX's SAC): the only ones a GPU can serve.  The SB3
#: runs train on the CPU (``device="cpu"``) and the classical baselines are numpy and numba.
GPU_ALGOS = ("sac", "residual_sac")


def _jax_sees_a_gpu() -> bool:
    import jax

    return any(d.platform == "gpu" for d in jax.devices())


def gpus_of(spec: RunSpec, gpu_available: bool) -> int:
    """The GPUs a run asks Ray for: one for a run that computes on JAX where JAX sees a GPU, else
    none (a CPU run holding a GPU would keep a GPU run waiting for nothing)."""
    return 1 if gpu_available and spec.algo in GPU_ALGOS else 0


def _run_ray(todo: list[RunSpec], out: str, threads: int, address: str | None, retries: int,
             result: dict[str, list[str]], log: Callable[[str], None], t0: float,
             packages: Sequence[str] = ()) -> dict[str, list[str]]:
    try:
        import ray
    except ImportError:
        raise ImportError('the Ray executor needs Ray: pip install "vnhc-gym[sweep]"') from None
    started_here = not ray.is_initialized()
    if started_here:
        ray.init(address=address or os.environ.get("RAY_ADDRESS"), include_dashboard=False, log_to_driver=False,
                 ignore_reinit_error=True)
    remote = ray.remote(num_cpus=threads, num_gpus=0, max_retries=retries, retry_exceptions=True)(run_one)
    gpu = _jax_sees_a_gpu()
    pending = {remote.options(num_gpus=gpus_of(s, gpu)).remote(s, out, threads, packages): s for s in todo}
    try:
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            spec = pending.pop(ready[0])
            try:
                ray.get(ready[0])
                result["done"].append(spec.stem)
            except Exception as exc:  # noqa: BLE001 - retries are exhausted: record and go on
                err = Path(out) / "runs" / f"{spec.stem}.error"
                err.parent.mkdir(parents=True, exist_ok=True)
                err.write_text("".join(traceback.format_exception(exc)))
                result["failed"].append(spec.stem)
                log(f"sweep: {spec.stem} failed after {retries} retries: {type(exc).__name__}: {exc}")
            _progress(len(result["done"]), len(result["failed"]), len(pending), len(todo), t0, log)
    except KeyboardInterrupt:
        for ref in pending:
            ray.cancel(ref, force=True)
        log("sweep: interrupted; finished runs are kept")
        raise
    finally:
        if started_here:
            ray.shutdown()
    return result


# --------------------------------------------------------------------------- report
def load_runs(out: str | Path, *, skipped: bool = False) -> list[dict[str, Any]]:
    """Every finished run's sidecar under ``out/runs`` (with ``skipped``, also the records of baselines
    that cannot act in their cell, which hold no test)."""
    runs = [json.loads(p.read_text()) for p in sorted((Path(out) / "runs").glob("*.json"))]
    return runs if skipped else [r for r in runs if not r.get("skipped")]


def save_records(out: str | Path, path: str | Path) -> int:
    """Write every finished run's sidecar of ``out`` into one gzipped JSON-lines file ``path``: the
    raw records a report is made from (every test episode's metrics, the learning curves, the
    settings), small enough to publish beside it.  Returns the number of records."""
    import gzip

    runs = load_runs(out, skipped=True)
    with gzip.open(path, "wt", encoding="utf-8") as fh:
        for r in runs:
            fh.write(json.dumps(r, sort_keys=True) + "\n")
    return len(runs)


def restore_records(path: str | Path, out: str | Path) -> int:
    """Write each record of a `save_records` file as a finished run's sidecar under ``out/runs``
    (unless that run is already there), so that a sweep over ``out`` skips those runs and its report
    includes them: how a published grid is continued, or its report remade, on another machine.
    The restored runs have no model files.  Returns the number of sidecars written."""
    import gzip

    runs = Path(out) / "runs"
    runs.mkdir(parents=True, exist_ok=True)
    written = 0
    with gzip.open(path, "rt", encoding="utf-8") as fh:
        for line in fh:
            r = json.loads(line)
            dest = runs / f"{r['name']}.json"
            if not dest.exists():
                _atomic_json(dest, r)
                written += 1
    return written


@dataclass
class Cell:
    env: str
    scenario: str
    runs: dict[str, list[dict[str, Any]]] = field(default_factory=dict)


def _episodes(rs: list[dict[str, Any]], metric: str) -> NDArray[np.float64]:
    """The test episodes' values of ``metric``, pooled over a cell's runs of one algorithm."""
    return np.concatenate([np.asarray(r["test"]["metrics"][metric], dtype=np.float64) for r in rs])


def _by_run(rs: list[dict[str, Any]], metric: str) -> NDArray[np.float64]:
    """The test episodes' values of ``metric``, a row per run: ``(n_runs, n_episodes)``, the shape the
    intervals of `vnhc_gym.stats` resample (the runs, then the episodes within each)."""
    rows = [np.asarray(r["test"]["metrics"][metric], dtype=np.float64) for r in rs]
    if len({row.size for row in rows}) > 1:
        raise ValueError(f"the runs of one cell and algorithm must have as many test episodes each, got "
                         f"{ {r['name']: row.size for r, row in zip(rs, rows, strict=True)} }")
    return np.stack(rows)


def _parity(r: dict[str, Any], target: float, residual: bool) -> tuple[float | None, float | None]:
    """Env steps and training seconds from the agent's own start until its validation score reaches
    ``target`` (a residual agent, which starts at its base: until the lower end of its score's
    interval is above its base's validation score, i.e. it beats its base), or ``None``."""
    curve = [p for p in r.get("curve", []) if p["steps"] > 0 and "score" in p]
    if residual:
        start = next((p for p in r.get("curve", []) if p["steps"] == 0 and "score" in p), None)
        if start is None:
            return None, None
        hit = next((p for p in curve if p["score_low"] > start["score"]), None)
    else:
        hit = next((p for p in curve if p["score"] >= target), None)
    return (None, None) if hit is None else (float(hit["steps"]), float(hit["wall"]))


def _validation_score(r: dict[str, Any]) -> float:
    """A run's validation score: a classical run's tuned setting's, a learned run's best checkpoint's
    (the model its test evaluates).  Choices between algorithms read this, never the test episodes."""
    if "validation_score" in r:
        return float(r["validation_score"])
    return max((float(p["score"]) for p in r.get("curve", []) if "score" in p), default=-math.inf)


#: Bootstrap replicates of every interval of a report: rliable's default.  A verdict compares an end
#: of an interval with 0.5, and with 2000 replicates the Monte Carlo error of that end (about 0.005
#: on the probability of improvement) can decide a verdict by itself; with 50 000 it is about 0.001.
REPORT_REPS = 50_000


def report(out: str | Path, reps: int = REPORT_REPS, log: Callable[[str], None] = print) -> dict[str, Any]:
    """Tables and figures from the run outputs alone (wherever they ran), in ``out/report``.

    Per cell (environment, scenario) and algorithm: the mean ``score`` over the test episodes of
    all its runs with its 95 % two-level bootstrap interval (`vnhc_gym.stats.interval_estimates`:
    the training runs redrawn, then the episodes within each drawn run; a classical baseline or the
    oracle is one run), the success rate (episodes that reached the time limit), and the
    diagnostics (the IQM of the completed steps' ``mean |phi~|``, the termination-aware mean
    ``|phi~|``).  The cell's best classical baseline and its best learned agent are the ones with
    the highest *validation* score (chosen without the test episodes); the oracle is the headroom
    reference.  For each learned agent: the probability that one of its episodes scores above one
    of the best classical baseline's, with its interval (the agent's runs and their episodes
    redrawn, and the baseline's episodes: `vnhc_gym.stats.probability_of_improvement_interval`),
    and the median env steps and seconds to parity (`_parity`) over its runs, or "not reached".
    Every row and verdict states the runs x episodes it rests on.  ``reps``: bootstrap replicates of
    each interval (`REPORT_REPS` by default).
    Files: ``comparison.{json,csv,md}`` (every row), ``headline.md`` (one line a cell: the oracle,
    the best classical, the best learned and the verdict), ``verdict.png`` (the same at a glance),
    ``learning_curves_<env>.png`` and ``performance_profile.png``.
    """
    from vnhc_gym import stats

    runs = load_runs(out)
    dest = Path(out) / "report"
    dest.mkdir(parents=True, exist_ok=True)
    codes = sorted({r.get("code", "?") for r in runs})
    if len(codes) > 1:
        log(f"report: WARNING: the runs come from {len(codes)} code versions {codes}; numbers may not compare")
    cells: dict[tuple[str, str], Cell] = {}
    for r in runs:
        spec = r["spec"]
        if "score" not in r["test"]["metrics"]:
            log(f"report: {r['name']} has no score (an older format): skipped")
            continue
        cell = cells.setdefault((spec["env"], spec["scenario"]), Cell(spec["env"], spec["scenario"]))
        cell.runs.setdefault(spec["algo"], []).append(r)
    rows: list[dict[str, Any]] = []
    for (env, scenario), cell in sorted(cells.items()):
        classical = {a: rs[0] for a, rs in cell.runs.items() if a in CLASSICAL_ALGOS}
        best_name = max(classical, key=lambda a: classical[a]["validation_score"]) if classical else None
        best_scores = _by_run([classical[best_name]], SCORE) if best_name else None
        for algo, rs in sorted(cell.runs.items()):
            values = _by_run(rs, SCORE)  # (runs, episodes): a classical baseline has one run
            iv = stats.interval_estimates({"x": values}, metric="mean", reps=reps)["x"]
            row: dict[str, Any] = {
                "env": env, "scenario": scenario, "algo": algo, "runs": len(rs), "episodes": int(values.size),
                "episodes_per_run": int(values.shape[1]), "score": iv.point, "low": iv.low, "high": iv.high,
                "success": float(np.mean(_episodes(rs, "success"))),
                "iqm_abs_phi_sf": stats.iqm(_episodes(rs, "mean_abs_phi_sf")),
                "horizon_abs_phi_sf": float(np.mean(_episodes(rs, "horizon_abs_phi_sf"))),
                "validation_score": float(np.mean([_validation_score(r) for r in rs])),
                "kind": "learned" if algo in LEARNED_ALGOS else "reference" if algo in REFERENCE_ALGOS else "classical",
                "best_classical": best_name,
                "settings": rs[0].get("settings"),
            }
            if "solve_seconds_per_step" in rs[0]:  # the planning baseline's cost, beside its score
                row["solve_ms_per_step"] = 1e3 * float(np.mean([r["solve_seconds_per_step"] for r in rs]))
            if algo in LEARNED_ALGOS and best_scores is not None:
                poi = stats.probability_of_improvement_interval(values, best_scores, reps=reps)
                row.update({"poi": poi.point, "poi_low": poi.low, "poi_high": poi.high})
                target = float(classical[best_name]["validation_score"])  # type: ignore[index]
                reached = [_parity(r, target, algo in RESIDUAL_ALGOS) for r in rs]
                hit = [p for p in reached if p[0] is not None]
                row["parity_runs"] = f"{len(hit)}/{len(rs)}"
                # The median over the runs, counting a run that never got there as slower than any
                # that did: defined only when at least half of the runs reached parity.
                if 2 * len(hit) > len(rs):
                    missing = [math.inf] * (len(rs) - len(hit))
                    order = sorted(float(p[0] or 0.0) for p in hit) + missing
                    walls = sorted(float(p[1] or 0.0) for p in hit) + missing
                    row["parity_steps"] = order[(len(rs) - 1) // 2]
                    row["parity_seconds"] = walls[(len(rs) - 1) // 2]
                else:
                    row["parity_steps"] = row["parity_seconds"] = None
            rows.append(row)
    (dest / "comparison.json").write_text(json.dumps(rows, indent=1))
    _write_tables(rows, dest)
    verdicts = _write_headline(rows, dest)
    figures = [*_verdict_figure(rows, dest), *_figures(cells, dest)]
    log(f"report: {len(runs)} runs, {len(cells)} cells -> {dest}")
    return {"rows": rows, "verdicts": verdicts, "figures": figures, "codes": codes}


def _fmt(x: float | None) -> str:
    return "n/a" if x is None else f"{x:.3g}"


def _score(r: dict[str, Any]) -> str:
    return f"{r['score']:.4f} [{r['low']:.4f}, {r['high']:.4f}]"


def _basis(r: dict[str, Any]) -> str:
    """The data a row rests on, e.g. ``"5 runs x 20 episodes"``."""
    n = int(r["runs"])
    return f"{n} run{'' if n == 1 else 's'} x {int(r['episodes_per_run'])} episodes"


def _p(v: float) -> str:
    """A probability to two decimals, or three where two would round an end onto 0.5 (where the verdict
    turns): 0.499 and 0.501 must not both read 0.50."""
    return f"{v:.3f}" if v != 0.5 and f"{v:.2f}" == "0.50" else f"{v:.2f}"


def _poi(r: dict[str, Any]) -> str:
    return f"{_p(r['poi'])} [{_p(r['poi_low'])}, {_p(r['poi_high'])}]"


def _parity_text(r: dict[str, Any]) -> tuple[str, str]:
    if "parity_runs" not in r:
        return "", ""
    if r["parity_steps"] is None:
        return f"not reached ({r['parity_runs']})", "not reached"
    return f"{r['parity_steps']:.3g} ({r['parity_runs']})", f"{r['parity_seconds']:.0f}"


def _write_tables(rows: list[dict[str, Any]], dest: Path) -> None:
    import csv

    keys = ["env", "scenario", "algo", "kind", "runs", "episodes_per_run", "episodes", "score", "low", "high",
            "success", "iqm_abs_phi_sf", "horizon_abs_phi_sf", "best_classical", "poi", "poi_low", "poi_high",
            "parity_steps", "parity_seconds", "parity_runs", "solve_ms_per_step"]
    with open(dest / "comparison.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=keys, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)
    lines = []
    for env in sorted({r["env"] for r in rows}):
        lines += [f"### {env}", "",
                  "| scenario | algo | runs x episodes | score [95% CI] | success | IQM mean abs phi~ "
                  "| P(beats best classical) | steps to parity | s to parity |",
                  "|---|---|---:|---|---:|---:|---|---:|---:|"]
        for r in (r for r in rows if r["env"] == env):
            best = " (best)" if r["algo"] == r["best_classical"] else ""
            if "solve_ms_per_step" in r:
                best += f" ({r['solve_ms_per_step']:.0f} ms/step)"
            steps, secs = _parity_text(r)
            lines.append(f"| {r['scenario']} | {r['algo']}{best} | {r['runs']} x {r['episodes_per_run']} | {_score(r)} "
                         f"| {r['success']:.2f} | "
                         f"{_fmt(r['iqm_abs_phi_sf'])} | {_poi(r) if 'poi' in r else ''} | {steps} | {secs} |")
        lines.append("")
    (dest / "comparison.md").write_text("\n".join(lines))


def verdict(best_learned: dict[str, Any] | None, best: dict[str, Any] | None) -> tuple[str, str]:
    """The verdict of a cell, ``(winner, words)``, from the best learned agent's probability of
    improvement over the best classical baseline: its interval above 0.5 (``"learned"``), below 0.5
    (``"classical"``), across it (``"none"``), or no learned agent yet (``"incomplete"``).  The
    words name the runs x episodes of both sides, the data the verdict rests on."""
    if best_learned is None or best is None or "poi" not in best_learned:
        return "incomplete", "incomplete"
    learned, classical = best_learned["algo"], best["algo"]
    if best_learned["poi_low"] > 0.5:
        return "learned", f"{learned} beats {classical} ({_basis(best_learned)} vs {_basis(best)})"
    if best_learned["poi_high"] < 0.5:
        return "classical", (f"{classical} beats every learned agent ({learned}, {_basis(best_learned)}, "
                             f"vs {_basis(best)})")
    return "none", f"no clear winner ({learned}, {_basis(best_learned)}, vs {classical}, {_basis(best)})"


def _cell_rows(rows: list[dict[str, Any]]) -> list[tuple[str, str, dict[str, dict[str, Any]]]]:
    cells = sorted({(r["env"], r["scenario"]) for r in rows})
    return [(e, s, {r["algo"]: r for r in rows if r["env"] == e and r["scenario"] == s}) for e, s in cells]


def _write_headline(rows: list[dict[str, Any]], dest: Path) -> list[dict[str, Any]]:
    """``headline.md``: a line a cell: the oracle, the best classical baseline, the best learned agent
    (the highest mean validation score over its runs), each with the score's interval and success
    rate, the probability of improvement, steps and seconds to parity, and the verdict with the runs
    x episodes it rests on."""
    lines = ["Mean score over held-out test episodes (the return over the fixed horizon per step, in [0, 1]; "
             "a failed episode's remaining steps count 0), its 95 % bootstrap interval and the success rate "
             "(episodes that reached the time limit). P: the probability that an episode of the best learned agent "
             "scores above one of the best classical baseline's, with its 95 % interval (**bold**: above 0.5). "
             "A learned agent's intervals redraw its training runs, then the test episodes within each run; a "
             "classical baseline is one run. Each verdict names the runs x episodes it rests on.", "",
             "| env | scenario | oracle | best classical | best learned | P | steps / s to parity | verdict |",
             "|---|---|---|---|---|---|---|---|"]
    verdicts = []
    for env, scenario, cell in _cell_rows(rows):
        oracle = cell.get("oracle")
        best = next((r for r in cell.values() if r["algo"] == r["best_classical"]), None)
        learned = [r for r in cell.values() if r["kind"] == "learned"]
        # Chosen on validation episodes, like the best classical baseline: picking the agent with the
        # best test score would bias its probability of improvement upwards.
        top = max(learned, key=lambda r: r["validation_score"]) if learned else None
        winner, words = verdict(top, best)
        why = _why(winner, oracle, best, top, learned)
        verdicts.append({"env": env, "scenario": scenario, "verdict": words, "winner": winner, "why": why,
                         "best_classical": best["algo"] if best else None, "best_learned": top["algo"] if top else None,
                         "poi_low": top.get("poi_low") if top else None,
                         "learned_runs_x_episodes": [top["runs"], top["episodes_per_run"]] if top else None,
                         "classical_runs_x_episodes": [best["runs"], best["episodes_per_run"]] if best else None})

        def entry(r: dict[str, Any] | None, name: bool = True) -> str:
            if r is None:
                return ""
            return (f"{r['algo']} " if name else "") + f"{_score(r)}, {r['success']:.0%}"

        poi = ""
        if top is not None and "poi" in top:
            poi = f"**{_poi(top)}**" if top["poi_low"] > 0.5 else _poi(top)
        steps, secs = _parity_text(top) if top is not None else ("", "")
        lines.append(f"| {env} | {scenario} | {entry(oracle, name=False)} | {entry(best)} | {entry(top)} | {poi} | "
                     f"{steps} / {secs} | {words}{': ' + why if why else ''} |")
    lines += ["", *_verdict_summary(verdicts)]
    (dest / "headline.md").write_text("\n".join(lines) + "\n")
    (dest / "verdicts.json").write_text(json.dumps(verdicts, indent=1))
    return verdicts


#: A best classical baseline this close to the oracle (in score) leaves nothing measurable to win.
NO_HEADROOM = 0.005


def _why(winner: str, oracle: dict[str, Any] | None, best: dict[str, Any] | None, top: dict[str, Any] | None,
         learned: list[dict[str, Any]]) -> str:
    """The reason behind a cell's verdict, in words, from its numbers: how much the best learned agent
    gains or loses, which one finishes more episodes, how much the oracle leaves to win, and whether
    residual agents ever left their base."""
    if winner == "incomplete" or best is None or top is None:
        return ""
    parts = []
    gap = top["score"] - best["score"]
    finishes = (f"{top['algo']} finishes {top['success']:.0%} of the episodes, {best['algo']} {best['success']:.0%}"
                if top["success"] != best["success"] else "")
    if winner == "learned":
        return "; ".join(p for p in (f"{gap:+.4f} in score", finishes) if p)
    if gap >= 5e-5:  # a gap that shows at the printed precision
        if top["poi"] > 0.5:
            # The pairwise majority too, but an end of the interval on the other side of 0.5: the
            # spread between its training runs and episodes leaves no difference possible.
            parts.append(f"{top['algo']} has the higher mean ({gap:+.4f}) and wins {_p(top['poi'])} of the pairwise "
                         f"comparisons, but the interval reaches {_p(top['poi_low'])}")
        else:
            # A higher mean without the pairwise majority: the classical baseline's episodes mostly score
            # higher, and a few of them (typically failures) pull its mean down.
            parts.append(f"{top['algo']} has the higher mean ({gap:+.4f}) but not most pairwise comparisons")
        if finishes:
            parts.append(finishes)
    if oracle is not None:
        headroom = oracle["score"] - best["score"]
        if headroom < -NO_HEADROOM:
            fails = f": it fails {1 - oracle['success']:.0%} of the episodes" if oracle["success"] < 1 else ""
            parts.append(f"the oracle scores below the best classical ({headroom:+.4f}{fails})")
        elif headroom >= 0 and headroom <= NO_HEADROOM:
            parts.append(f"no headroom (the oracle is {headroom:+.4f} above the best classical)")
        elif headroom < 0:
            parts.append(f"no headroom (the oracle is {-headroom:.4f} below the best classical)")
    residual = [r for r in learned if r["algo"] in RESIDUAL_ALGOS]
    if residual and all(r.get("parity_steps") is None for r in residual):
        parts.append("no residual run beat its base on validation")
    scratch = [r for r in learned if r["algo"] not in RESIDUAL_ALGOS]
    if scratch:
        behind = best["score"] - max(r["score"] for r in scratch)
        if behind > 0:
            parts.append(f"from scratch {behind:.4f} behind")
    return "; ".join(parts)


def _verdict_summary(verdicts: list[dict[str, Any]]) -> list[str]:
    """The verdicts grouped in words: where learning wins, where it loses, where neither is shown."""
    def cells(pred: Callable[[dict[str, Any]], bool]) -> str:
        hit = [f"{v['env']}/{v['scenario']}" for v in verdicts if pred(v)]
        return ", ".join(hit) if hit else "none"

    return [f"- **A learned agent beats the best classical baseline** (interval above 0.5): "
            f"{cells(lambda v: v['winner'] == 'learned')}.",
            f"- **The best classical baseline beats every learned agent** (interval below 0.5): "
            f"{cells(lambda v: v['winner'] == 'classical')}.",
            f"- **No clear winner** (interval across 0.5): {cells(lambda v: v['winner'] == 'none')}.",
            f"- Cells without a finished learned run: {cells(lambda v: v['winner'] == 'incomplete')}."]


#: One look per algorithm in every figure: classical baselines dashed or dotted, agents solid.
_STYLE: dict[str, dict[str, Any]] = {
    "law": {"color": "black", "ls": "--"}, "tuned_law": {"color": "tab:purple", "ls": "--"},
    "observer": {"color": "tab:brown", "ls": ":"}, "adaptive": {"color": "tab:gray", "ls": "-."},
    "kalman": {"color": "tab:pink", "ls": ":"}, "safe_law": {"color": "darkviolet", "ls": "-."},
    "oracle": {"color": "gold", "ls": "-"}, "mpc": {"color": "tab:cyan", "ls": "--"},
    "ppo": {"color": "tab:blue"}, "ppo_history": {"color": "tab:orange"}, "residual_ppo": {"color": "tab:green"},
    "sac": {"color": "tab:red"}, "residual_sac": {"color": "tab:olive"},
}


def _verdict_figure(rows: list[dict[str, Any]], dest: Path) -> list[str]:
    """``verdict.png``: per task a panel, the scenarios down, every algorithm's test score with its
    interval across, as the reward lost over the horizon (``1 - score``, log axis: good controllers
    differ in the third decimal of the score); the oracle is a star, the cell's best classical
    baseline a ringed marker."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    envs = sorted({r["env"] for r in rows})
    if not envs:
        return []
    algos = [a for a in (*REFERENCE_ALGOS, *CLASSICAL_ALGOS, *LEARNED_ALGOS) if any(r["algo"] == a for r in rows)]
    n_scen = max(len({r["scenario"] for r in rows if r["env"] == e}) for e in envs)
    fig, axes = plt.subplots(1, len(envs), figsize=(4.2 * len(envs), 0.9 + 0.55 * n_scen * 1.6), squeeze=False)
    for ax, env in zip(axes[0], envs, strict=True):
        scen = sorted({r["scenario"] for r in rows if r["env"] == env})
        for j, algo in enumerate(algos):
            for i, scenario in enumerate(scen):
                r = next((r for r in rows if r["env"] == env and r["scenario"] == scenario and r["algo"] == algo), None)
                if r is None:
                    continue
                y = i + (j - (len(algos) - 1) / 2) * 0.8 / max(1, len(algos))
                style = _STYLE.get(algo, {})
                marker = "*" if algo == "oracle" else "s" if r["kind"] == "classical" else "o"
                lost, lo, hi = (max(1.0 - v, 1e-5) for v in (r["score"], r["high"], r["low"]))
                ax.errorbar(lost, y, xerr=[[max(0.0, lost - lo)], [max(0.0, hi - lost)]],
                            fmt=marker, color=style.get("color"), ms=7 if algo == "oracle" else 4, lw=1,
                            label=algo if i == 0 else None)
                if algo == r["best_classical"]:
                    ax.plot(lost, y, "o", mfc="none", mec="red", ms=10, mew=1.2, label="best classical")
        ax.set_yticks(range(len(scen)), scen)
        ax.invert_yaxis()
        ax.set_xscale("log")
        ax.set_xlabel("1 - test score (mean, 95 % CI; lower is better)")
        ax.set_title(env, fontsize=10)
        ax.grid(axis="x", alpha=0.3)
    handles, labels = [], []
    for ax in axes[0]:
        for h, lab in zip(*ax.get_legend_handles_labels(), strict=True):
            if lab not in labels:
                handles.append(h)
                labels.append(lab)
    fig.legend(handles, labels, loc="lower center", ncol=min(len(labels), 5), fontsize=7)
    fig.tight_layout(rect=(0, 0.12, 1, 1))
    path = dest / "verdict.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return [str(path)]


def _figures(cells: dict[tuple[str, str], Cell], dest: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files = []
    envs = sorted({env for env, _ in cells})
    for env in envs:
        scen = sorted(s for e, s in cells if e == env)
        fig, axes = plt.subplots(1, len(scen), figsize=(3.2 * len(scen), 3.0), squeeze=False)
        for ax, scenario in zip(axes[0], scen, strict=True):
            cell = cells[(env, scenario)]
            for algo, rs in sorted(cell.runs.items()):
                if algo in LEARNED_ALGOS:
                    curves = [[p for p in r["curve"] if "score" in p] for r in rs if r.get("curve")]
                    curves = [c for c in curves if c]
                    if not curves:
                        continue
                    n = min(len(c) for c in curves)
                    steps = np.array([curves[0][i]["steps"] for i in range(n)])
                    vals = np.median(np.array([[c[i][SCORE] for i in range(n)] for c in curves]), axis=0)
                    ax.plot(steps, vals, label=algo, **_STYLE.get(algo, {}))
                else:
                    ax.axhline(rs[0]["validation_score"], lw=1, label=algo, **_STYLE.get(algo, {}))
            ax.set_title(scenario, fontsize=9)
            ax.set_xlabel("env steps")
        axes[0][0].set_ylabel("validation score (median over seeds)")
        axes[0][-1].legend(fontsize=6)
        fig.tight_layout()
        path = dest / f"learning_curves_{env}.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        files.append(str(path))
    # Performance profile: each run's test score over the oracle's in its cell (1: the headroom is used
    # up), the fraction of runs at or above each level.
    ratios: dict[str, list[float]] = {}
    for cell in cells.values():
        oracle = cell.runs.get("oracle")
        if not oracle:
            continue
        ref = float(np.mean(_episodes(oracle, SCORE)))
        if ref <= 0:
            continue
        for algo, rs in cell.runs.items():
            for r in rs:
                ratios.setdefault(algo, []).append(float(np.mean(_episodes([r], SCORE))) / ref)
    if ratios:
        taus = np.linspace(0.0, 1.1, 111)
        fig, ax = plt.subplots(figsize=(5, 3.5))
        for algo, vals in sorted(ratios.items()):
            v = np.asarray(vals)
            ax.plot(taus, [(v >= t).mean() for t in taus], label=algo, **_STYLE.get(algo, {}))
        ax.set_xlabel("test score / the oracle's (per cell)")
        ax.set_ylabel("fraction of runs at or above")
        ax.legend(fontsize=7)
        fig.tight_layout()
        path = dest / "performance_profile.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        files.append(str(path))
    return files


# --------------------------------------------------------------------------- command line
def add_arguments(parser: Any) -> None:
    """The options of ``vnhc-gym sweep``."""
    parser.add_argument("--config", help="a YAML file with any of the options below (command-line values win)")
    parser.add_argument("--envs", nargs="+", help="tasks or env ids (default: every registered task)")
    parser.add_argument("--scenarios", nargs="+", help="scenarios (default: nominal)")
    parser.add_argument("--algos", nargs="+", help=f"from {list(ALL_ALGOS)} (default: law ppo)")
    parser.add_argument("--seeds", nargs="+", type=int, help="training seeds (default: 0)")
    parser.add_argument("-n", "--n-timesteps", type=int, help="training budget per learned run (default: 1e6)")
    parser.add_argument("--out", help="output folder (default: runs/sweep); on a cluster, shared storage")
    parser.add_argument("--executor", choices=["local", "ray"], help="local processes or Ray (default: ray if "
                        "installed, else local)")
    parser.add_argument("--address", help="Ray cluster address (default: $RAY_ADDRESS, else a local instance)")
    parser.add_argument("--jobs", type=int, help="local executor: parallel runs (default: 1)")
    parser.add_argument("--threads", type=int, help="torch threads per run (default: 1)")
    parser.add_argument("--test-episodes", type=int, help="held-out test episodes per run (default: 20)")
    parser.add_argument("--report", metavar="DIR", help="only build the report of the runs in DIR")


def _options(args: Any) -> dict[str, Any]:
    from vnhc_gym.tasks import TASKS

    opts: dict[str, Any] = {"envs": list(TASKS), "scenarios": ["nominal"], "algos": ["law", "ppo"],
                            "seeds": [0], "n_timesteps": 1_000_000, "out": "runs/sweep", "executor": None,
                            "address": None, "jobs": 1, "threads": 1, "test_episodes": 20, "seeds_by_scenario": None}
    if args.config:
        import yaml

        with open(args.config) as fh:
            data = yaml.safe_load(fh) or {}
        unknown = sorted(set(data) - set(opts))
        if unknown:
            raise ValueError(f"unknown keys {unknown} in {args.config}; valid: {sorted(opts)}")
        opts.update(data)
    for key in opts:
        value = getattr(args, key, None)
        if value is not None:
            opts[key] = value
    if opts["executor"] is None:
        try:
            import ray  # noqa: F401

            opts["executor"] = "ray"
        except ImportError:
            opts["executor"] = "local"
    return opts


def run(args: Any) -> int:
    """``vnhc-gym sweep``: run the grid, then build its report."""
    if args.report:
        report(args.report)
        return 0
    o = _options(args)
    specs = grid(o["envs"], o["scenarios"], o["algos"], o["seeds"], int(o["n_timesteps"]),
                 test_episodes=int(o["test_episodes"]), seeds_by_scenario=o["seeds_by_scenario"])
    result = run_sweep(specs, o["out"], executor=o["executor"], jobs=int(o["jobs"]), threads=int(o["threads"]),
                       address=o["address"], packages=list(getattr(args, "gym_packages", None) or []))
    report(o["out"])
    if result["failed"]:
        print(f"sweep: {len(result['failed'])} runs failed (tracebacks in {o['out']}/runs/*.error):")
        for stem in result["failed"]:
            print(f"  {stem}")
        return 1
    return 0
