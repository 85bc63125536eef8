"""``vnhc-gym benchmark``: every policy on every environment and scenario.

Policies
--------
``zero``
    no force (the uncontrolled system).
``random``
    uniform random actions (seeded).
``geometric``
    :class:`~vnhc_gym.baselines.GeometricController`, ``variant="plain"``: the paper's law
    ``u*`` from the observation and the nominal model, held over the control period.
``geometric-sampled``
    the same with ``variant="sampled"``: the held control that makes ``phi`` after one period
    of the nominal RK4 map equal ``exp(-k dt) phi`` (zero-order-hold aware).
``inloop-oracle``
    reference, not an observation-based policy: the law runs *inside the integrator* at every
    RK4 stage on the **true state** with the nominal parameters
    (``task.set_feedback("continuous")``, action 0); the theorem's continuous-time setting.
    Observation noise cannot affect it; the force bound still applies.
trained agents
    every ``<env-short>-<algo>.zip`` (Stable-Baselines3) found in the agent folders (below).

Every policy runs ``--episodes`` episodes (default 10, seeds ``--seed + i``, default
``--seed 10000`` so agents trained on small seeds are evaluated on held-out ones) of
``--max-time`` seconds (20 s; the ``coarse`` scenario runs 200 steps of 0.1 s, the others 400 of
0.05 s) on both environments and all six scenarios (``vnhc_gym.envs.SCENARIOS``), and the
metrics of :mod:`vnhc_gym.evaluation` are aggregated per cell as IQM with a 95 % bootstrap CI.

Trained agents
--------------
Agent folders: ``vnhc_gym/agents_zoo/`` inside the installed package (agents shipped with
vnhc_gym; skipped with ``--no-zoo``) and every ``--agents DIR``.  An agent is a
Stable-Baselines3 zip named ``<env-short>-<algo>.zip`` with ``env-short`` in ``flocking``,
``usv`` and ``algo`` an SB3 algorithm in lower case (``ppo``, ``sac``, ``td3``, ``a2c``,
``ddpg``), optionally prefixed ``residual_`` for an agent trained inside
:class:`~vnhc_gym.wrappers.ResidualAction` (e.g. ``flocking-ppo.zip``,
``usv-residual_ppo.zip``), plus an optional JSON sidecar with the same stem::

    {"algo": "PPO",                       # SB3 class name (default: from the file name)
     "env_id": "vnhc_gym/USVStream-v0",   # default: from env-short
     "residual": {"scale": 0.2, "continuous": false, "gain": 1.0},   # residual agents only
     "env_kwargs": {},                    # extra env arguments used in training (optional)
     "description": "..."}

This is the format ``vnhc-gym train`` writes (:mod:`vnhc_gym.train`); PPO and SAC agents are
loaded with its ``load_agent`` (observation normalisation from the sidecar; a residual agent's
base controller rebuilt for every evaluated scenario, so it uses that scenario's force bound and
``dt``), other algorithms as plain SB3 models on the raw observation.  Agents are loaded lazily
(only when evaluated).  SB3 zips contain pickled Python objects: loading one from a user folder
runs code from it, so a warning is issued; only load agents you trust.  Agents are skipped with
a message if stable-baselines3 is not installed; an agent that fails to load or run is
reported and skipped.

Outputs (``--out``, default ``results/benchmark``)
--------------------------------------------------
``benchmark.csv`` (one row per env x scenario x policy: IQM, CI and mean of every metric),
``benchmark_episodes.csv`` (one row per episode), ``benchmark.md`` (tables),
``benchmark.json`` (settings, summaries, episodes and the median ``|phi|(t)`` per cell) and
``phi_<env>.png`` (median ``|phi|(t)`` over episodes per policy, log scale, one panel per
scenario).  ``--quick`` (2 episodes of 2 s) is for tests and CI.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vnhc_gym.baselines.geometric import DEFAULT_GAIN

__all__ = ["add_arguments", "run", "PolicySpec", "find_agents", "default_policies", "run_benchmark", "ZOO_DIR"]

#: Agents shipped inside the package.
ZOO_DIR = Path(__file__).resolve().parent / "agents_zoo"
ENV_SHORT = {"flocking": "vnhc_gym/FlockingAlign-v0", "usv": "vnhc_gym/USVStream-v0"}
BASELINES = ("zero", "random", "geometric", "geometric-sampled", "inloop-oracle")
SB3_ALGOS = ("ppo", "sac", "td3", "a2c", "ddpg", "dqn")


@dataclass
class PolicySpec:
    """A policy to benchmark: a factory ``make(env) -> policy`` and an optional env wrapper."""

    name: str
    make: Callable[[Any], Any]
    wrapper: Callable[[Any], Any] | None = None
    envs: tuple[str, ...] = tuple(ENV_SHORT)
    source: str = "baseline"
    info: dict[str, Any] = field(default_factory=dict)


def default_policies(gain: float = DEFAULT_GAIN, seed: int = 0) -> list[PolicySpec]:
    """The baseline policies (module docstring)."""
    from vnhc_gym.baselines import GeometricController, RandomPolicy, ZeroPolicy
    from vnhc_gym.wrappers import ResidualAction

    def inloop(env: Any) -> Any:
        return ResidualAction(env, scale=0.0, continuous=True, gain=gain)

    return [
        PolicySpec("zero", ZeroPolicy),
        PolicySpec("random", lambda env: RandomPolicy(env, seed)),
        PolicySpec("geometric", lambda env: GeometricController(env, gain=gain)),
        PolicySpec("geometric-sampled", lambda env: GeometricController(env, gain=gain, variant="sampled")),
        PolicySpec("inloop-oracle", ZeroPolicy, wrapper=inloop),
    ]


def _parse_agent_name(stem: str) -> tuple[str, str, bool] | None:
    env_short, sep, algo = stem.partition("-")
    if not sep or env_short not in ENV_SHORT:
        return None
    residual = algo.startswith("residual_")
    base_algo = algo[len("residual_"):] if residual else algo
    if base_algo not in SB3_ALGOS:
        return None
    return env_short, base_algo, residual


def find_agents(dirs: list[Path], trusted: set[Path] | None = None, log: Callable[[str], None] = print
                ) -> list[PolicySpec]:
    """Agent :class:`PolicySpec` s for the SB3 zips in ``dirs`` (module docstring); nothing is loaded yet.

    ``trusted`` folders (the package zoo) are loaded without the pickle warning.
    """
    found: list[tuple[Path, str, str, bool, dict[str, Any]]] = []
    for d in dirs:
        if not d.is_dir():
            if d != ZOO_DIR:
                log(f"[benchmark] agent folder {d} does not exist; skipped")
            continue
        for path in sorted(d.glob("*.zip")):
            parsed = _parse_agent_name(path.stem)
            if parsed is None:
                log(f"[benchmark] {path.name}: not named <flocking|usv>-<[residual_]algo>.zip; skipped")
                continue
            sidecar = path.with_suffix(".json")
            meta: dict[str, Any] = {}
            if sidecar.exists():
                try:
                    meta = json.loads(sidecar.read_text())
                except (OSError, ValueError) as exc:
                    log(f"[benchmark] {sidecar.name}: unreadable sidecar ({exc}); skipped")
                    continue
                if not isinstance(meta, dict):
                    log(f"[benchmark] {sidecar.name}: not a JSON object; skipped")
                    continue
            found.append((path, *parsed, meta))
    if not found:
        return []
    try:
        import stable_baselines3  # noqa: F401
    except ImportError:
        log(f"[benchmark] {len(found)} agent(s) found but stable-baselines3 is not installed; skipped "
            "(pip install 'vnhc-gym[rl]')")
        return []
    trusted_dirs = {t.resolve() for t in (trusted or set())}
    specs = []
    for path, env_short, algo, residual, meta in found:
        env_id = meta.get("env_id", ENV_SHORT[env_short])
        if env_id != ENV_SHORT[env_short]:
            log(f"[benchmark] {path.name}: sidecar env_id {env_id!r} does not match {env_short!r}; skipped")
            continue
        res = dict(meta.get("residual") or {}) if residual else {}
        in_loop = bool(res.get("continuous", False))
        loader = _LazyAgent(path, algo, meta, warn=path.parent.resolve() not in trusted_dirs, raw=in_loop)
        wrapper = None
        if in_loop:
            from vnhc_gym.wrappers import ResidualAction

            scale, gain = float(res.get("scale", 0.2)), res.get("gain", res.get("base_gain"))

            def wrapper(env: Any, scale: float = scale, gain: Any = gain) -> Any:
                return ResidualAction(env, scale=scale, continuous=True, gain=gain)

        name = path.stem.split("-", 1)[1]
        specs.append(PolicySpec(name, loader, wrapper=wrapper, envs=(env_short,), source=str(path), info=meta))
    return specs


class _LazyAgent:
    """Factory ``make(env) -> policy`` that loads an SB3 agent on first use (and keeps it).

    With :mod:`vnhc_gym.train` available the agent is loaded by its ``load_agent`` (observation
    normalisation from the sidecar, residual base controller bound to each evaluation env, so
    the base uses that scenario's force bound and ``dt``).  Otherwise (or for in-loop residual
    agents, which run inside :class:`~vnhc_gym.wrappers.ResidualAction`) the SB3 model itself is
    the policy, with the sidecar's observation normalisation applied if present, and a
    residual agent gets its base from :class:`~vnhc_gym.wrappers.ResidualPolicy`.
    """

    def __init__(self, path: Path, algo: str, meta: dict[str, Any], warn: bool, raw: bool = False) -> None:
        self.path, self.algo, self.meta, self.warn, self.raw = path, algo, meta, warn, raw
        self.agent: Any = None
        parsed = _parse_agent_name(path.stem)
        self.residual = parsed[2] if parsed is not None else False

    def _load(self) -> Any:
        if not self.raw and self.algo in ("ppo", "sac"):
            try:
                from vnhc_gym.train import load_agent
            except ImportError:
                pass
            else:
                return load_agent(self.path)  # warns itself for files outside the package zoo
        if self.warn:
            warnings.warn(f"loading {self.path}: Stable-Baselines3 zips contain pickled Python objects that run "
                          "code when loaded; only load agents you trust", stacklevel=3)
        import stable_baselines3 as sb3

        cls = getattr(sb3, str(self.meta.get("algo", self.algo)).upper(), None)
        if cls is None:
            raise ValueError(f"unknown SB3 algorithm {self.meta.get('algo', self.algo)!r}")
        return _RawAgent(cls.load(str(self.path), device="cpu"), self.meta.get("obs_normalization"))

    def __call__(self, env: Any) -> Any:
        if self.agent is None:
            self.agent = self._load()
        if hasattr(self.agent, "bind"):
            return self.agent.bind(env)
        if self.residual and not self.raw:
            from vnhc_gym.baselines import GeometricController
            from vnhc_gym.wrappers import ResidualPolicy

            res = dict(self.meta.get("residual") or {})
            gain = res.get("gain", res.get("base_gain"))
            base = GeometricController(env, gain=1.0 if gain is None else gain,
                                       variant=str(res.get("base_variant", "plain")))
            return ResidualPolicy(self.agent, base, scale=float(res.get("scale", 0.2)))
        return self.agent


class _RawAgent:
    """An SB3 model on raw observations (optional saved normalisation ``{"mean", "var", ...}``)."""

    def __init__(self, model: Any, rms: dict[str, Any] | None) -> None:
        self.model = model
        self.rms = rms

    def predict(self, obs: Any, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[Any, Any]:
        o = np.asarray(obs, dtype=np.float64)
        if self.rms is not None:
            r = self.rms
            o = np.clip((o - np.asarray(r["mean"])) / np.sqrt(np.asarray(r["var"]) + float(r.get("epsilon", 1e-8))),
                        -float(r.get("clip_obs", 10.0)), float(r.get("clip_obs", 10.0)))
        a, _ = self.model.predict(o.astype(np.float32), deterministic=deterministic)
        return np.clip(np.asarray(a, dtype=np.float32), -1.0, 1.0), None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``vnhc-gym benchmark``."""
    from vnhc_gym.envs.task import SCENARIOS

    parser.add_argument("--episodes", type=int, default=None, help="episodes per cell (default 10; --quick: 2)")
    parser.add_argument("--max-time", type=float, default=None,
                        help="episode length in seconds (default 20; --quick: 2)")
    parser.add_argument("--seed", type=int, default=10_000,
                        help="episode i uses seed SEED + i (default 10000: held out)")
    parser.add_argument("--out", type=Path, default=Path("results/benchmark"), help="output folder")
    parser.add_argument("--quick", action="store_true", help="2 episodes of 2 s per cell (tests, CI)")
    parser.add_argument("--envs", nargs="+", choices=list(ENV_SHORT), default=list(ENV_SHORT))
    parser.add_argument("--scenarios", nargs="+", choices=list(SCENARIOS), default=list(SCENARIOS))
    parser.add_argument("--policies", nargs="+", choices=list(BASELINES), default=list(BASELINES),
                        help="baseline policies (trained agents are added unless --no-agents)")
    parser.add_argument("--gain", type=float, default=DEFAULT_GAIN,
                        help=f"gain k of the geometric law (default {DEFAULT_GAIN}; the paper's is 1)")
    parser.add_argument("--agents", type=Path, action="append", default=[],
                        help="extra folder of SB3 agents <env>-<algo>.zip (repeatable; pickles: trusted files only)")
    parser.add_argument("--no-zoo", action="store_true", help="skip the agents shipped in vnhc_gym/agents_zoo")
    parser.add_argument("--no-agents", action="store_true", help="skip all trained agents")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--no-figures", action="store_true", help="skip the phi_<env>.png figures")


def run_benchmark(policies: list[PolicySpec], envs: list[str], scenarios: list[str], episodes: int, max_time: float,
                  seed: int, progress: bool = True, log: Callable[[str], None] = print) -> list[Any]:
    """Evaluate every policy on every env and scenario; returns the :class:`EvalResult` list."""
    from tqdm.auto import tqdm

    from vnhc_gym.evaluation import evaluate

    cells = [(e, s, p) for e in envs for s in scenarios for p in policies if e in p.envs]
    results = []
    bar = tqdm(cells, desc="benchmark", unit="cell", disable=not progress, file=sys.stderr, dynamic_ncols=True)
    for env_short, scenario, spec in bar:
        bar.set_postfix_str(f"{env_short}/{scenario}/{spec.name}", refresh=False)
        try:
            res = evaluate(spec.make, ENV_SHORT[env_short], scenario, n_episodes=episodes, seed=seed,
                           max_time=max_time, wrapper=spec.wrapper, name=spec.name)
        except Exception as exc:  # a broken agent must not kill the whole benchmark
            if spec.source == "baseline":
                raise
            log(f"[benchmark] {spec.name} on {env_short}/{scenario} failed: {type(exc).__name__}: {exc}; skipped")
            continue
        results.append(res)
    bar.close()
    return results


def _pivot(results: list[Any], metric: str, policies: list[str], fmt: str = ".3g") -> str:
    envs = list(dict.fromkeys(r.env_short for r in results))
    lines = []
    for env in envs:
        rows = [r for r in results if r.env_short == env]
        scen = list(dict.fromkeys(r.scenario for r in rows))
        pols = [p for p in policies if any(r.policy == p for r in rows)]
        lines.append(f"\n**{env}**: {metric}, IQM [95% CI]\n")
        lines.append("| scenario | " + " | ".join(pols) + " |")
        lines.append("|---|" + "---|" * len(pols))
        for s in scen:
            cells = []
            for p in pols:
                match = [r for r in rows if r.scenario == s and r.policy == p]
                cells.append(match[0].summary()[metric].format(fmt) if match else "")
            lines.append(f"| {s} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _figures(results: list[Any], out: Path, policies: list[str]) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    from matplotlib.ticker import LogLocator, NullLocator

    paths = []
    for env in dict.fromkeys(r.env_short for r in results):
        rows = [r for r in results if r.env_short == env]
        scen = list(dict.fromkeys(r.scenario for r in rows))
        ncol = min(3, len(scen))
        nrow = int(np.ceil(len(scen) / ncol))
        fig, axes = plt.subplots(nrow, ncol, figsize=(4.2 * ncol, 3.0 * nrow + 0.6), squeeze=False, sharey=True)
        pols = [p for p in policies if any(r.policy == p for r in rows)]
        colors = {p: f"C{i % 10}" for i, p in enumerate(pols)}
        for ax, s in zip(axes.ravel(), scen, strict=False):
            for r in rows:
                if r.scenario != s or r.phi_series.size == 0:
                    continue
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", RuntimeWarning)
                    med = np.nanmedian(r.phi_series, axis=0)
                ok = np.isfinite(med)
                ax.semilogy(r.times[ok], np.maximum(med[ok], 1e-14), color=colors[r.policy], label=r.policy, lw=1.3)
            ax.set_title(s, fontsize=10)
            ax.yaxis.set_major_locator(LogLocator(base=10.0, numticks=6))
            ax.yaxis.set_minor_locator(NullLocator())
            ax.grid(True, which="major", alpha=0.3)
        for ax in axes.ravel()[len(scen):]:
            ax.set_visible(False)
        for ax in axes[-1, :]:
            ax.set_xlabel("t (s)")
        for ax in axes[:, 0]:
            ax.set_ylabel("median |phi|")
        handles, labels = axes.ravel()[0].get_legend_handles_labels()
        fig.legend(handles, labels, loc="lower center", ncol=min(len(labels), 6), frameon=False, fontsize=9)
        unit = "m^2/s^2" if env == "flocking" else "m/s"
        fig.suptitle(f"{env}: median |phi|(t) over episodes ({unit}), floored at 1e-14", fontsize=11)
        fig.subplots_adjust(left=0.08, right=0.98, top=0.9, bottom=0.2 if nrow == 1 else 0.14, wspace=0.08,
                            hspace=0.35)
        path = out / f"phi_{env}.png"
        fig.savefig(path, dpi=100)
        plt.close(fig)
        paths.append(path)
    return paths


def write_outputs(results: list[Any], out: Path, settings: dict[str, Any], policies: list[str],
                  figures: bool = True) -> dict[str, Path]:
    """Write the CSV, Markdown, JSON (and PNG) outputs; returns their paths."""
    import csv

    from vnhc_gym.evaluation import _jsonable, markdown_table, results_to_csv

    out.mkdir(parents=True, exist_ok=True)
    paths = {"csv": out / "benchmark.csv", "episodes": out / "benchmark_episodes.csv", "md": out / "benchmark.md",
             "json": out / "benchmark.json"}
    results_to_csv(results, paths["csv"])
    rows = [row for r in results for row in r.episodes()]
    with open(paths["episodes"], "w", newline="") as fh:
        if rows:
            writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
    table = markdown_table(results, ("mean_abs_phi", "late_abs_phi", "return"))
    last_seed = settings["seed"] + settings["episodes"] - 1
    md = [
        "# vnhc-gym benchmark",
        "",
        f"{settings['episodes']} episodes per cell (seeds {settings['seed']}..{last_seed}), "
        f"{settings['max_time']:g} s each; geometric gain k = {settings['gain']:g}. "
        "Cells: IQM [95% percentile-bootstrap CI] over episodes. `mean_abs_phi` is the mean of |phi| over the "
        "episode (flocking: m^2/s^2, USV: m/s), `late_abs_phi` the mean over its second half; `return` the "
        "undiscounted reward sum. `terminated` counts "
        "episodes ended early (USV: boat left the domain). `inloop-oracle` runs the law inside the integrator on the "
        "true state (not an observation-based policy).",
        "",
        f"Command: `{settings['command']}` ({settings['wall_time']:.1f} s, {settings['platform']}).",
        "",
        table,
        "",
        "## mean |phi| by scenario",
        _pivot(results, "mean_abs_phi", policies),
        "",
        "## late |phi|: mean over the second half of the episode (after the transient)",
        _pivot(results, "late_abs_phi", policies),
        "",
        "## time until |phi| < 0.01 |phi(0)| (s; inf: never)",
        _pivot(results, "time_to_eps", policies),
        "",
        "## control energy sum(force^2) dt (N^2 s)",
        _pivot(results, "energy", policies),
        "",
    ]
    paths["md"].write_text("\n".join(md))
    payload: dict[str, Any] = {"settings": settings, "results": []}
    for r in results:
        d = r.to_dict(series=False)
        if r.phi_series.size:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                med = np.nanmedian(r.phi_series, axis=0)
            d["median_phi_series"] = [float(f"{v:.6g}") for v in med]  # at t = k * dt, k = 0..max_steps
        payload["results"].append(d)
    paths["json"].write_text(json.dumps(_jsonable(payload), indent=1))
    if figures:
        for p in _figures(results, out, policies):
            paths[p.stem] = p
    return paths


def _command_line(args: argparse.Namespace) -> str:
    """The equivalent command line (for the report)."""
    parts = ["vnhc-gym benchmark"]
    if args.quick:
        parts.append("--quick")
    for flag, value in (("--episodes", args.episodes), ("--max-time", args.max_time)):
        if value is not None:
            parts.append(f"{flag} {value}")
    if args.seed != 10_000:
        parts.append(f"--seed {args.seed}")
    if args.gain != 1.0:
        parts.append(f"--gain {args.gain}")
    for flag, value, default in (("--envs", args.envs, list(ENV_SHORT)), ("--scenarios", args.scenarios, None),
                                 ("--policies", args.policies, list(BASELINES))):
        from vnhc_gym.envs.task import SCENARIOS

        if list(value) != (default if default is not None else list(SCENARIOS)):
            parts.append(f"{flag} {' '.join(value)}")
    parts += [f"--agents {a}" for a in args.agents]
    parts += [flag for flag, on in (("--no-zoo", args.no_zoo), ("--no-agents", args.no_agents)) if on]
    parts.append(f"--out {args.out}")
    return " ".join(parts)


def run(args: argparse.Namespace) -> int:
    """Run the benchmark from parsed arguments; returns the exit code."""
    t0 = time.perf_counter()
    episodes = args.episodes if args.episodes is not None else (2 if args.quick else 10)
    max_time = args.max_time if args.max_time is not None else (2.0 if args.quick else 20.0)
    if episodes < 1:
        print("error: --episodes must be >= 1", file=sys.stderr)
        return 2
    if not (np.isfinite(max_time) and max_time > 0):
        print("error: --max-time must be > 0", file=sys.stderr)
        return 2
    import vnhc_gym  # noqa: F401  (registers the environments)

    specs = [p for p in default_policies(args.gain, args.seed) if p.name in args.policies]
    agent_specs: list[PolicySpec] = []
    if not args.no_agents:
        dirs = ([] if args.no_zoo else [ZOO_DIR]) + list(args.agents)
        agent_specs = find_agents(dirs, trusted={ZOO_DIR}, log=lambda m: print(m, file=sys.stderr))
        taken = {s.name for s in specs}
        for a in agent_specs:
            if a.name in taken:
                a.name = f"{a.name}@{Path(a.source).parent.name}"
            taken.add(a.name)
    specs += agent_specs
    if agent_specs:
        print(f"[benchmark] agents: {', '.join(f'{a.name} ({a.envs[0]})' for a in agent_specs)}", file=sys.stderr)
    results = run_benchmark(specs, list(args.envs), list(args.scenarios), episodes, max_time, args.seed,
                            progress=not args.no_progress, log=lambda m: print(m, file=sys.stderr))
    from vnhc_gym.evaluation import markdown_table

    table = markdown_table(results, ("mean_abs_phi", "late_abs_phi", "return"))
    wall = time.perf_counter() - t0
    settings = {
        "command": _command_line(args), "episodes": episodes, "max_time": max_time, "seed": args.seed,
        "gain": args.gain,
        "envs": list(args.envs), "scenarios": list(args.scenarios), "policies": [s.name for s in specs],
        "agents": {a.name: a.source for a in agent_specs}, "wall_time": wall,
        "platform": f"{platform.system()} {platform.machine()}, Python {platform.python_version()}",
    }
    policy_order = list(dict.fromkeys(s.name for s in specs))
    paths = write_outputs(results, Path(args.out), settings, policy_order, figures=not args.no_figures)
    print(table)
    print(f"\n{len(results)} cells in {time.perf_counter() - t0:.1f} s; wrote "
          + ", ".join(str(p) for p in paths.values()))
    return 0
