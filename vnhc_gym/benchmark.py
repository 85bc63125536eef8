"""``vnhc-gym benchmark``: every baseline and shipped agent on every registered environment and scenario.

Policies
--------
``zero``, ``random``
    No force; uniform random actions (seeded).
``law``, ``law-sampled``
    The geometric law with k = 5 from the observation and the nominal model, held over the control
    period; and its sampled-data variant (the held control that makes ``phi`` after one period of
    the nominal RK4 map equal ``exp(-k dt) phi``).
``tuned_law``, ``observer``, ``adaptive``
    The classical baselines of [`vnhc_gym.baselines.tuning`][vnhc_gym.baselines.tuning] with the settings chosen on
    validation episodes for each cell (``vnhc_gym/baselines/settings.json``, written by
    ``experiments/train_compare.py --publish``; their defaults where a cell has none).
``inloop``
    A reference, not an observation-based policy: the law runs inside the integrator at every RK4
    stage on the true state with the nominal parameters (the theorem's continuous-time setting).
``oracle``
    The headroom reference (not an observation-based policy either): the sampled-data law on the
    environment's true state and parameters, its gain chosen per cell on validation episodes
    ([`OracleController`][vnhc_gym.baselines.OracleController]).
shipped agents
    ``<algo>@<scenario>`` from ``vnhc_gym/agents_zoo``: each agent runs only in the cell it was trained
    in (its task and scenario), so a row never shows an agent outside the conditions it learned.

Every policy runs ``--episodes`` held-out episodes (seeds 10 000 + i) of 20 s per cell.  The first
table is the ``score`` (the return over the fixed horizon per step, in [0, 1]: a failed episode's
remaining steps count 0; its mean with a 95 % bootstrap interval) and the success rate; the others
are diagnostics (IQMs of the completed steps' ``|phi~|``).  Outputs in ``--out`` (default
``results/benchmark``): ``benchmark.md`` (tables), ``benchmark.csv``, ``benchmark.json`` and
``phi_<task>.png`` (the median ``|phi~|(t)`` per policy, nominal scenario).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["PolicySpec", "add_arguments", "policies", "run", "run_benchmark", "settings"]

_SETTINGS = Path(__file__).resolve().parent / "baselines" / "settings.json"


@dataclass
class PolicySpec:
    """A policy of the benchmark: a factory ``make(env, task, scenario) -> policy``."""

    name: str
    make: Callable[[Any, str, str], Any]
    feedback: str | None = None


def settings() -> dict[str, Any]:
    """The tuned classical settings per task and scenario (empty if the file is missing)."""
    return json.loads(_SETTINGS.read_text()) if _SETTINGS.exists() else {}


def policies(quick: bool = False, agents: bool = True) -> list[PolicySpec]:
    """The benchmark's policies (module docstring); ``quick`` keeps the fast ones."""
    from vnhc_gym.baselines import GeometricController, RandomPolicy, ZeroPolicy, make_classical

    tuned = settings()

    def classical(name: str) -> Callable[[Any, str, str], Any]:
        def make(env: Any, task: str, scenario: str) -> Any:
            return make_classical(name, env, **tuned.get(task, {}).get(scenario, {}).get(name, {}))
        return make

    specs = [PolicySpec("zero", lambda env, t, s: ZeroPolicy(env)),
             PolicySpec("random", lambda env, t, s: RandomPolicy(env, seed=0)),
             PolicySpec("law", lambda env, t, s: GeometricController(env))]
    if not quick:
        specs += [PolicySpec("law-sampled", lambda env, t, s: GeometricController(env, variant="sampled")),
                  PolicySpec("tuned_law", classical("tuned_law")), PolicySpec("observer", classical("observer")),
                  PolicySpec("adaptive", classical("adaptive"))]
    specs.append(PolicySpec("inloop", lambda env, t, s: ZeroPolicy(env), feedback="continuous"))
    if not quick:
        specs.append(PolicySpec("oracle", classical("oracle")))
    if agents:
        specs += _agents()
    return specs


def _agents() -> list[PolicySpec]:
    """One spec per shipped agent, which applies only to the cell it was trained in."""
    from vnhc_gym.training.agents import ZOO_DIR, list_zoo, sidecar_of

    out = []
    for name in list_zoo():
        side = sidecar_of(ZOO_DIR / f"{name}.zip")
        task = name.partition("-")[0]
        algo = str(side.get("sweep_algo") or side.get("algo") or name.rpartition("-")[2])
        trained_on = str(side.get("scenario", "nominal"))

        def make(env: Any, t: str, s: str, name: str = name, task: str = task, trained_on: str = trained_on) -> Any:
            from vnhc_gym.training import load_agent

            return load_agent(name, env=env) if (t, s) == (task, trained_on) else None

        out.append(PolicySpec(f"{algo}@{trained_on}", make))
    return out


def run_benchmark(tasks: list[str], scenarios: list[str], specs: list[PolicySpec], episodes: int, seed: int,
                  max_time: float, log: Callable[[str], None]) -> list[Any]:
    """Every (task, scenario, policy) cell; returns the [`EvalResult`][vnhc_gym.evaluation.EvalResult] list."""
    from vnhc_gym.evaluation import evaluate
    from vnhc_gym.tasks import env_id

    results = []
    cells = [(t, s, p) for t in tasks for s in scenarios for p in specs]
    t0 = time.perf_counter()
    for i, (task, scenario, spec) in enumerate(cells):
        log(f"[{i + 1}/{len(cells)}] {task} / {scenario} / {spec.name} ({time.perf_counter() - t0:.0f} s so far)")

        def factory(env: Any, spec: PolicySpec = spec, task: str = task, scenario: str = scenario) -> Any:
            return spec.make(env, task, scenario)

        probe = _probe(factory, env_id(task), scenario)
        if probe is None:
            continue
        res = evaluate(factory, env_id(task), scenario, n_episodes=episodes, seed=seed, max_time=max_time,
                       feedback=spec.feedback)
        res.policy = spec.name
        results.append(res)
    return results


def _probe(factory: Callable[[Any], Any], env: str, scenario: str) -> Any:
    """The policy for a single env of the cell, or None when it does not apply (an agent of another task)."""
    import gymnasium as gym

    return factory(gym.make(env, scenario=scenario))


def _table(results: list[Any], metric: str, names: list[str]) -> str:
    from vnhc_gym.evaluation import AGGREGATE

    lines = []
    for task in sorted({r.env_id for r in results}):
        lines += [f"**{task}**: {metric}, {AGGREGATE.get(metric, 'iqm').upper()} [95% CI]", "",
                  "| scenario | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
        for scenario in dict.fromkeys(r.scenario for r in results if r.env_id == task):
            cells = []
            for name in names:
                r = next((r for r in results if r.env_id == task and r.scenario == scenario and r.policy == name), None)
                cells.append(r.summary(reps=1000)[metric].format() if r is not None else "")
            lines.append(f"| {scenario} | " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


def write_outputs(results: list[Any], out: Path, settings_used: dict[str, Any]) -> list[Path]:
    """``benchmark.md``, ``.csv``, ``.json`` and one figure per task in ``out``."""
    import csv

    out.mkdir(parents=True, exist_ok=True)
    names = list(dict.fromkeys(r.policy for r in results))
    md = ["# Benchmark", "", f"Command: `{settings_used['command']}`", "",
          _table(results, "score", names), _table(results, "success", names),
          _table(results, "mean_abs_phi_sf", names), _table(results, "late_abs_phi_sf", names),
          _table(results, "mean_abs_phi", names)]
    (out / "benchmark.md").write_text("\n".join(md))
    rows = []
    for r in results:
        row = {"env_id": r.env_id, "scenario": r.scenario, "policy": r.policy}
        for k, iv in r.summary(reps=1000).items():
            row.update({k: iv.point, f"{k}_low": iv.low, f"{k}_high": iv.high})
        rows.append(row)
    with open(out / "benchmark.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    (out / "benchmark.json").write_text(json.dumps({"settings": settings_used,
                                                    "results": [r.to_dict() for r in results]}, indent=1))
    return [out / "benchmark.md", out / "benchmark.csv", out / "benchmark.json", *_figures(results, out)]


def _figures(results: list[Any], out: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files = []
    styles = ["-", "--", "-.", ":"]
    for task in sorted({r.env_id for r in results}):
        rs = [r for r in results if r.env_id == task and r.scenario == "nominal"]
        if not rs:
            continue
        fig, ax = plt.subplots(figsize=(6, 3.6))
        for i, r in enumerate(rs):
            t = np.arange(r.abs_phi_sf.shape[0]) * r.dt
            with warnings.catch_warnings():  # all-NaN after every episode of a cell has ended
                warnings.simplefilter("ignore", RuntimeWarning)
                med = np.nanmedian(r.abs_phi_sf, axis=1)
            # Distinct styles and markers: curves that coincide (the law and a residual agent that
            # learned nothing) stay visible.
            ax.plot(t, med, styles[i % 4], marker="os^vDx*+"[i % 8], markevery=(i * 7 % 40 + 1, 40), ms=4,
                    lw=1.2, label=r.policy)
        ax.set_yscale("log")
        ax.set_xlabel("time (s)")
        ax.set_ylabel("median |phi~| (scale-free)")
        ax.set_title(f"{task}, nominal")
        ax.legend(fontsize=7, ncol=2)
        fig.tight_layout()
        path = out / f"phi_{task.split('/')[-1].split('-')[0]}.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        files.append(path)
    return files


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from vnhc_gym.envs.config import SCENARIOS
    from vnhc_gym.tasks import TASKS

    parser.add_argument("--tasks", nargs="+", default=list(TASKS), choices=list(TASKS))
    parser.add_argument("--scenarios", nargs="+", default=list(SCENARIOS), choices=list(SCENARIOS))
    parser.add_argument("--episodes", type=int, default=10, help="held-out episodes per cell (default 10)")
    parser.add_argument("--seed", type=int, default=10_000, help="first episode seed (default 10000)")
    parser.add_argument("--max-time", type=float, default=20.0, help="episode duration in seconds (default 20)")
    parser.add_argument("--out", default="results/benchmark", help="output folder (default results/benchmark)")
    parser.add_argument("--no-agents", action="store_true", help="skip the shipped agents")
    parser.add_argument("--quick", action="store_true",
                        help="3 episodes of 2 s, nominal and noisy, the fast baselines (smoke test)")


def run(args: argparse.Namespace) -> int:
    quick = bool(args.quick)
    episodes, max_time = (3, 2.0) if quick else (args.episodes, args.max_time)
    scenarios = ["nominal", "noisy"] if quick else args.scenarios
    agents = not args.no_agents and not quick
    if agents:
        try:
            import stable_baselines3  # noqa: F401
        except ImportError:
            print("benchmark: stable-baselines3 is not installed: shipped agents skipped "
                  '(pip install "vnhc-gym[rl]")', file=sys.stderr)
            agents = False
    specs = policies(quick=quick, agents=agents)
    t0 = time.perf_counter()
    results = run_benchmark(args.tasks, scenarios, specs, episodes, args.seed, max_time,
                            log=lambda s: print(s, file=sys.stderr, flush=True))
    command = "vnhc-gym benchmark" + (" --quick" if quick else "")
    files = write_outputs(results, Path(args.out), {"command": command, "episodes": episodes, "seed": args.seed,
                                                    "max_time": max_time, "wall": time.perf_counter() - t0})
    print((Path(args.out) / "benchmark.md").read_text())
    print(f"wrote {', '.join(str(f) for f in files)} in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    return 0
