"""``vnhc-gym train``: one training run from the command line (see `vnhc_gym.training.run`)."""

from __future__ import annotations

import argparse
import json
from dataclasses import fields

from vnhc_gym.training.config import ALGOS, BACKENDS, TrainConfig, default_backend

__all__ = ["add_arguments", "parse_key_values", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from vnhc_gym.envs.config import SCENARIOS

    d = TrainConfig()
    parser.add_argument("--algo", default=d.algo, choices=ALGOS, help=f"(default {d.algo})")
    parser.add_argument("--env", default=d.env, help=f"a task name or env id (default {d.env}, the latest version)")
    parser.add_argument("--scenario", default=d.scenario, choices=list(SCENARIOS), help=f"(default {d.scenario})")
    parser.add_argument("--seed", type=int, default=d.seed, help=f"(default {d.seed})")
    parser.add_argument("--seeds", type=int, nargs="+", default=None,
                        help="several seeds, trained in one compiled program (backend jax); replaces --seed")
    parser.add_argument("--backend", default=None, choices=BACKENDS,
                        help="jax: PPO or SAC compiled with the environment, either also as a residual on the law; "
                             "sb3: Stable-Baselines3 (SBX for SAC), whose model files RL Zoo loads (default: jax, "
                             "the faster, for the algorithms it trains; sb3 for recurrent_ppo)")
    parser.add_argument("-n", "--n-timesteps", type=int, default=None,
                        help="training budget (default: the hyperparameter file's)")
    parser.add_argument("--out", default=d.out, help=f"output folder (default {d.out})")
    parser.add_argument("--threads", type=int, default=d.threads, help=f"torch threads (default {d.threads})")
    parser.add_argument("--hyperparams", default=None, help="another RL Zoo file for the algorithm")
    parser.add_argument("-params", "--params", nargs="*", default=[], metavar="KEY:VALUE",
                        help="hyperparameter overrides, RL Zoo style (e.g. n_envs:64 learning_rate:1e-4)")
    parser.add_argument("--env-kwargs", nargs="*", default=[], metavar="KEY:VALUE",
                        help="arguments of the training environments only, RL Zoo style (e.g. reward:reciprocal); "
                             "validation and test use the environment's defaults")
    parser.add_argument("--eval-points", type=int, default=d.eval_points, help="validation evaluations over the run")
    parser.add_argument("--test-episodes", type=int, default=d.test_episodes)
    parser.add_argument("--progress-bar", action="store_true", help="show SB3's progress bar")


def parse_key_values(items: list[str], option: str = "--params") -> dict[str, object]:
    """``KEY:VALUE`` items as a dict (values parsed as Python literals where they are one)."""
    from vnhc_gym.training.hyperparams import parse_literal

    out: dict[str, object] = {}
    for item in items:
        key, sep, text = item.partition(":")
        if not sep or not key:
            raise ValueError(f"{option} takes KEY:VALUE items, got {item!r}")
        try:
            out[key] = parse_literal(text)
        except ValueError:
            out[key] = text  # a plain string such as lin_3e-4
    return out


def run(args: argparse.Namespace) -> int:
    from vnhc_gym.training.run import train

    names = {f.name for f in fields(TrainConfig)}
    given = {k: v for k, v in vars(args).items() if k in names and k not in ("overrides", "env_kwargs", "backend")}
    cfg = TrainConfig(**given, backend=args.backend or default_backend(args.algo),
                      overrides=parse_key_values(args.params),
                      env_kwargs=parse_key_values(args.env_kwargs, "--env-kwargs"))
    if args.seeds is not None and cfg.backend != "jax":
        raise SystemExit("--seeds trains several seeds in one program: it needs --backend jax (else one --seed a run)")
    if args.seeds is not None:
        from vnhc_gym.training.run_jax import train_seeds

        metas = train_seeds(cfg, args.seeds, log=print)
    else:
        metas = [train(cfg, log=print)]
    suffix = ".npz" if cfg.backend == "jax" else ".zip"
    for meta in metas:
        summary = {"model": f"{cfg.out}/{meta['name']}{suffix}", "steps": meta["n_timesteps"],
                   "steps_per_second": round(meta["steps_per_second"])}
        if meta["test"] is not None:  # --test-episodes 0 skips the test
            test = meta["test"]["summary"]
            summary.update({"test_score": test["score"], "test_success": test["success"],
                            "test_mean_abs_phi_sf_iqm": test["mean_abs_phi_sf"]})
        print(json.dumps(summary, indent=1))
    return 0
