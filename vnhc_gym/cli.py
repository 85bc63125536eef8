"""The ``vnhc-gym`` console command: ``benchmark``, ``train``, ``tune``, ``sweep``, ``reproduce``."""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

# subcommand -> (module, help); each module exposes add_arguments(parser) and run(args).
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "benchmark": ("vnhc_gym.benchmark", "Evaluate baselines (and shipped agents) on every env and scenario."),
    "train": ("vnhc_gym.training.cli", "Train one agent (PPO, residual PPO, recurrent PPO, SAC, residual SAC)."),
    "tune": ("vnhc_gym.training.tune", "Search hyperparameters or gains with Optuna (validation episodes only)."),
    "sweep": ("vnhc_gym.sweep", "Run a grid of training and evaluation runs (locally or on Ray) and report."),
    "reproduce": ("vnhc_gym.paper", "Regenerate the figures of the original paper's Section IV."),
}


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``vnhc-gym`` console script.

    Only the chosen subcommand's module is imported (they pull in matplotlib, SB3, torch...).
    """
    args_in = list(sys.argv[1:] if argv is None else argv)
    chosen = next((a for a in args_in if not a.startswith("-")), None)
    from vnhc_gym import __version__

    parser = argparse.ArgumentParser(prog="vnhc-gym", description=__doc__)
    parser.add_argument("--version", action="version", version=f"vnhc-gym {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    for name, (module_name, help_text) in SUBCOMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        if name == chosen:
            module = importlib.import_module(module_name)
            module.add_arguments(p)
            p.set_defaults(_run=module.run)
    args = parser.parse_args(args_in)
    try:
        return int(args._run(args) or 0)
    except ValueError as exc:  # a value argparse accepted but the command cannot use: a usage error
        parser.error(f"{args.command}: {exc}")


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
