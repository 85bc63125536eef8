"""The executors of a sweep: `run_one` (one run, its outputs and sidecar), `run_sweep` (every
unfinished run, in this process, in worker processes or on Ray) and the GPUs a run asks Ray for
(`gpus_of`)."""

from __future__ import annotations

import json
import multiprocessing
import os
import time
import traceback
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import numpy as np

from vnhc_gym.sweep.records import _atomic_json
from vnhc_gym.sweep.specs import CLASSICAL_ALGOS, PLANNING_ALGOS, RESIDUAL_ALGOS, RunSpec, status


def run_one(spec: RunSpec, out: str | Path, threads: int = 1, packages: Sequence[str] = ()) -> dict[str, Any]:
    """Do one run and write its outputs (the sidecar last); returns the sidecar.

    ``packages`` are imported first (``--gym-packages``: the modules that register a user's tasks,
    needed again in a worker process).
    """
    if spec.backend != "sb3":
        return run_seeds([spec], out, threads, packages)[0]
    from vnhc_gym.cli import import_gym_packages

    import_gym_packages(packages)
    runs = Path(out) / "runs"
    runs.mkdir(parents=True, exist_ok=True)
    (runs / f"{spec.stem}.error").unlink(missing_ok=True)
    import vnhc_gym
    from vnhc_gym.training.config import code_fingerprint, resolve_env_id

    env_id = resolve_env_id(spec.env)
    t0 = time.perf_counter()
    if spec.learned:
        from vnhc_gym.training import train

        meta = train(_train_config(spec, out, env_id, threads))
        meta["sweep_algo"] = spec.label
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


def _train_config(spec: RunSpec, out: str | Path, env_id: str, threads: int) -> Any:
    """The `TrainConfig` of a learned run: its files under ``out/runs`` named by its stem; the
    history variant as PPO with 4 stacked frames; a residual agent's base read from its cell."""
    from vnhc_gym.training import TrainConfig

    algo = "ppo" if spec.algo == "ppo_history" else spec.algo
    overrides = dict(spec.overrides)
    if spec.algo == "ppo_history":
        overrides.setdefault("frame_stack", 4)
    base, settings = _best_classical(spec, out, env_id) if algo in RESIDUAL_ALGOS else (None, None)
    return TrainConfig(algo=algo, env=spec.env, scenario=spec.scenario, seed=spec.seed,
                       n_timesteps=spec.n_timesteps, out=str(Path(out) / "runs"), threads=threads, name=spec.stem,
                       eval_episodes=spec.eval_episodes, test_episodes=spec.test_episodes, overrides=overrides,
                       residual_base=base, residual_base_settings=settings, backend=spec.backend)


def run_seeds(specs: Sequence[RunSpec], out: str | Path, threads: int = 1,
              packages: Sequence[str] = ()) -> list[dict[str, Any]]:
    """Runs of the compiled backend that differ only in their seed, trained in one program
    (`vnhc_gym.training.run_jax.train_seeds`); writes each run's sidecar (last) and returns them.
    Each run's ``run_wall`` is the whole program's."""
    specs = list(specs)
    first = specs[0]
    if first.backend != "jax" or any(replace(s, seed=first.seed) != first for s in specs):
        raise ValueError(f"run_seeds takes runs of the jax backend that differ only in their seed, got "
                         f"{[s.stem for s in specs]}")
    from vnhc_gym.cli import import_gym_packages

    import_gym_packages(packages)
    runs = Path(out) / "runs"
    runs.mkdir(parents=True, exist_ok=True)
    for s in specs:
        (runs / f"{s.stem}.error").unlink(missing_ok=True)
    from vnhc_gym.training.config import resolve_env_id
    from vnhc_gym.training.run_jax import train_seeds

    t0 = time.perf_counter()
    cfg = _train_config(first, out, resolve_env_id(first.env), threads)
    metas = train_seeds(cfg, [s.seed for s in specs], names=[s.stem for s in specs])
    wall = time.perf_counter() - t0
    for s, meta in zip(specs, metas, strict=True):
        meta.update({"sweep_algo": s.label, "spec": asdict(s), "run_wall": wall})
        _atomic_json(runs / f"{s.stem}.json", meta)
    return metas


def units(specs: Sequence[RunSpec]) -> list[list[RunSpec]]:
    """The sweep's units of work, in the order of ``specs``: the compiled backend's runs of one
    cell and configuration together (their seeds train in one program), every other run alone."""
    out: list[list[RunSpec]] = []
    together: dict[str, list[RunSpec]] = {}
    for s in specs:
        if s.backend == "sb3":
            out.append([s])
            continue
        key = replace(s, seed=0).key()  # (a spec's overrides may hold dicts: the spec itself is not hashable)
        if key not in together:
            together[key] = []
            out.append(together[key])
        together[key].append(s)
    return out


def _run_unit(unit: Sequence[RunSpec], out: str | Path, threads: int, packages: Sequence[str]) -> None:
    """Run a unit of work (`units`): one run, or the seeds of a compiled cell in one program."""
    if len(unit) == 1:
        run_one(unit[0], out, threads, packages)
    else:
        run_seeds(unit, out, threads, packages)


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


def _guarded(unit: Sequence[RunSpec], out: str, threads: int,
             packages: Sequence[str] = ()) -> list[tuple[str, str | None]]:
    """A unit of runs (`units`) that records a failure (with its traceback, for each of its runs)
    instead of raising; returns each run's stem and error."""
    try:
        _run_unit(unit, out, threads, packages)
        return [(s.stem, None) for s in unit]
    except Exception:  # noqa: BLE001 - a failed run is recorded, the sweep goes on
        tb = traceback.format_exc()
        for s in unit:
            err = Path(out) / "runs" / f"{s.stem}.error"
            err.parent.mkdir(parents=True, exist_ok=True)
            err.write_text(tb)
        return [(s.stem, tb) for s in unit]


def _progress(done: int, failed: int, running: int, total: int, t0: float, log: Callable[[str], None]) -> None:
    finished = done + failed
    eta = (time.perf_counter() - t0) / finished * (total - finished) if finished else float("nan")
    log(f"sweep: {done} done, {running} running, {failed} failed of {total}"
        + (f"; about {eta / 60:.0f} min left" if np.isfinite(eta) else ""))


def run_sweep(specs: Iterable[RunSpec], out: str | Path, *, executor: str = "local", jobs: int = 1, threads: int = 1,
              address: str | None = None, retries: int = 2, rerun_failed: bool = True,
              log: Callable[[str], None] = print, packages: Sequence[str] = ()) -> dict[str, list[str]]:
    """Run every unfinished spec; returns ``{"done": [...], "failed": [...], "skipped": [...]}``.

    ``executor="local"`` runs in this process (``jobs=1``) or in ``jobs`` worker processes; ``"ray"``
    submits one task per unit of work (`units`: a run, or the seeds of a compiled run) to Ray
    (``address``: an existing cluster, else a local instance; ``RAY_ADDRESS`` works too). Ctrl-C stops
    the sweep; finished runs stay. ``packages``: modules every run imports first (``--gym-packages``).
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
        for unit in units(todo):
            _progress(len(result["done"]), len(result["failed"]), len(unit), len(todo), t0, log)
            for stem, err in _guarded(unit, out, threads, packages):
                result["failed" if err else "done"].append(stem)
                if err:
                    log(f"sweep: {stem} failed:\n{err.strip().splitlines()[-1]}")
        return result
    # Workers are spawned, not forked: a fork of a process in which JAX's threads run can deadlock
    # (JAX warns of it), and the parent has imported JAX whenever a task or the compiled trainer did.
    with ProcessPoolExecutor(max_workers=jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
        futures = [pool.submit(_guarded, u, out, threads, packages) for u in units(todo)]
        for fut in as_completed(futures):
            for stem, err in fut.result():
                result["failed" if err else "done"].append(stem)
            finished = len(result["done"]) + len(result["failed"])
            _progress(len(result["done"]), len(result["failed"]), min(jobs, len(todo) - finished), len(todo), t0, log)
    return result


#: Runs that compute on JAX's default device (SBX's SAC, and every run of the compiled backend): the
#: only ones a GPU can serve.  The SB3 runs train on the CPU (``device="cpu"``) and the classical
#: baselines run their JAX models on the CPU in float64.
GPU_ALGOS = ("sac", "residual_sac")


def _jax_sees_a_gpu() -> bool:
    import jax

    return any(d.platform == "gpu" for d in jax.devices())


def gpus_of(spec: RunSpec, gpu_available: bool) -> int:
    """The GPUs a run asks Ray for: one for a run that computes on JAX where JAX sees a GPU, else
    none (a CPU run holding a GPU would keep a GPU run waiting for nothing)."""
    return 1 if gpu_available and (spec.algo in GPU_ALGOS or spec.backend == "jax") else 0


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
    remote = ray.remote(num_cpus=threads, num_gpus=0, max_retries=retries, retry_exceptions=True)(_run_unit)
    gpu = _jax_sees_a_gpu()
    pending = {remote.options(num_gpus=gpus_of(u[0], gpu)).remote(u, out, threads, packages): u for u in units(todo)}
    try:
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            unit = pending.pop(ready[0])
            try:
                ray.get(ready[0])
                result["done"] += [s.stem for s in unit]
            except Exception as exc:  # noqa: BLE001 - retries are exhausted: record and go on
                for spec in unit:
                    err = Path(out) / "runs" / f"{spec.stem}.error"
                    err.parent.mkdir(parents=True, exist_ok=True)
                    err.write_text("".join(traceback.format_exception(exc)))
                    result["failed"].append(spec.stem)
                    log(f"sweep: {spec.stem} failed after {retries} retries: {type(exc).__name__}: {exc}")
            _progress(len(result["done"]), len(result["failed"]), sum(map(len, pending.values())), len(todo), t0,
                      log)
    except KeyboardInterrupt:
        for ref in pending:
            ray.cancel(ref, force=True)
        log("sweep: interrupted; finished runs are kept")
        raise
    finally:
        if started_here:
            ray.shutdown()
    return result
