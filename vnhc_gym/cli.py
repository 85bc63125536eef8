"""The ``vnhc-gym`` console command: ``reproduce``, ``benchmark``, ``train``."""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

# subcommand -> "module:function"; each module exposes add_arguments(parser) and run(args).
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "reproduce": ("vnhc_gym.paper", "Regenerate the paper's Section IV figures."),
    "benchmark": ("vnhc_gym.benchmark", "Evaluate baselines (and shipped agents) on every env and scenario."),
}


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``vnhc-gym`` console script."""
    parser = argparse.ArgumentParser(prog="vnhc-gym", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    for name, (module_name, help_text) in SUBCOMMANDS.items():
        module = importlib.import_module(module_name)
        p = sub.add_parser(name, help=help_text, description=help_text)
        module.add_arguments(p)
        p.set_defaults(_run=module.run)
    args = parser.parse_args(argv)
    return int(args._run(args) or 0)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
