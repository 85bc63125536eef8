"""``vnhc-gym sweep``: its options (`add_arguments`, a YAML file's keys) and the command (`run`): the
grid, then its report."""

from __future__ import annotations

from typing import Any

from vnhc_gym.sweep.execute import run_sweep
from vnhc_gym.sweep.reporting import report
from vnhc_gym.sweep.specs import ALL_ALGOS, grid


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
    parser.add_argument("--backend", choices=["sb3", "jax"], help="where PPO and SAC from scratch train: sb3, or "
                        "jax (compiled with the environment, a cell's seeds in one program); other learners train "
                        "on sb3 (default: sb3)")
    parser.add_argument("--test-episodes", type=int, help="held-out test episodes per run (default: 20)")
    parser.add_argument("--report", metavar="DIR", help="only build the report of the runs in DIR")


def _options(args: Any) -> dict[str, Any]:
    from vnhc_gym.tasks import TASKS

    opts: dict[str, Any] = {"envs": list(TASKS), "scenarios": ["nominal"], "algos": ["law", "ppo"],
                            "seeds": [0], "n_timesteps": 1_000_000, "out": "runs/sweep", "executor": None,
                            "address": None, "jobs": 1, "threads": 1, "test_episodes": 20, "seeds_by_scenario": None,
                            "backend": "sb3"}
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
                 test_episodes=int(o["test_episodes"]), seeds_by_scenario=o["seeds_by_scenario"],
                 backend=o["backend"])
    result = run_sweep(specs, o["out"], executor=o["executor"], jobs=int(o["jobs"]), threads=int(o["threads"]),
                       address=o["address"], packages=list(getattr(args, "gym_packages", None) or []))
    report(o["out"])
    if result["failed"]:
        print(f"sweep: {len(result['failed'])} runs failed (tracebacks in {o['out']}/runs/*.error):")
        for stem in result["failed"]:
            print(f"  {stem}")
        return 1
    return 0
