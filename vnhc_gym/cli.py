"""The ``vnhc-gym`` console command: ``benchmark``, ``train``, ``tune``, ``sweep``, ``reproduce``."""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from collections.abc import Sequence

# subcommand -> (module, help); each module exposes add_arguments(parser) and run(args).
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "benchmark": ("vnhc_gym.benchmark", "Evaluate baselines (and shipped agents) on every env and scenario."),
    "train": ("vnhc_gym.training.cli", "Train one agent (PPO, residual PPO, recurrent PPO, SAC, residual SAC)."),
    "tune": ("vnhc_gym.training.tune", "Search hyperparameters or gains with Optuna (validation episodes only)."),
    "sweep": ("vnhc_gym.sweep.cli", "Run a grid of training and evaluation runs (locally or on Ray) and report."),
    "reproduce": ("vnhc_gym.paper", "Regenerate the figures of the original paper's Section IV."),
}


#: Subcommands that take an environment, and so ``--gym-packages``.
TAKES_ENV = ("benchmark", "train", "tune", "sweep")

GYM_PACKAGES_HELP = ("modules to import first, so that the tasks they register exist (RL Zoo's flag): "
                     "a task defined in a file of your own, e.g. --gym-packages puck_task")


def import_gym_packages(names: Sequence[str]) -> None:
    """Import each module of ``names`` (a user's task modules, which register their tasks on import),
    from the Python path or the current directory.

    Raises
    ------
    ValueError
        Naming the module that cannot be imported and why.
    """
    if names and "" not in sys.path and os.getcwd() not in sys.path:
        # A console script's path does not hold the current directory (``python -m`` does): add it,
        # so a task module beside the user's files imports as it does in their own scripts.
        sys.path.insert(0, os.getcwd())
    for name in names:
        try:
            importlib.import_module(name)
        except ImportError as exc:
            raise ValueError(f"--gym-packages: cannot import {name!r} ({exc}); is its folder on the Python path "
                             f"(PYTHONPATH, or the current directory)?") from None


def use_compilation_cache() -> str | None:
    """Keep JAX's compiled programs on disk for the next ``vnhc-gym`` command (JAX's persistent
    compilation cache: compiled XLA programs, never Python code), so a command run again skips the
    compilations of the last one.

    Only the console command does this: it is a global JAX setting, which importing the package never
    changes.  The folder is ``$VNHC_GYM_JAX_CACHE``, else ``$XDG_CACHE_HOME/vnhc_gym/jax`` (or
    ``~/.cache/vnhc_gym/jax``); ``VNHC_GYM_JAX_CACHE=off`` turns it off, and a cache folder the user
    already gave JAX (``JAX_COMPILATION_CACHE_DIR``) is kept.

    Returns
    -------
    str or None
        The folder in use, or None when off.
    """
    import jax

    chosen = os.environ.get("VNHC_GYM_JAX_CACHE", "")
    if chosen.lower() == "off":
        return None
    given = getattr(jax.config, "jax_compilation_cache_dir", None)
    if given:
        return str(given)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    folder = chosen or os.path.join(base, "vnhc_gym", "jax")
    jax.config.update("jax_compilation_cache_dir", folder)
    # JAX caches only compilations above one second by default; most of the environments' and the
    # baselines' programs compile in less, and together they are most of a short command's time.
    if "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS" not in os.environ:
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    # The processes the command starts (the sweep's workers) read the same folder.
    os.environ["JAX_COMPILATION_CACHE_DIR"] = folder
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
    return folder


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``vnhc-gym`` console script.

    Only the chosen subcommand's module is imported (they pull in matplotlib, SB3, torch...).
    ``--gym-packages`` modules are imported before the subcommand builds its options, so that a
    task they register is one of its choices.
    """
    args_in = list(sys.argv[1:] if argv is None else argv)
    chosen = next((a for a in args_in if not a.startswith("-")), None)
    from vnhc_gym import __version__

    parser = argparse.ArgumentParser(prog="vnhc-gym", description=__doc__)
    parser.add_argument("--version", action="version", version=f"vnhc-gym {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    if chosen in TAKES_ENV:
        early = argparse.ArgumentParser(add_help=False)
        early.add_argument("--gym-packages", nargs="+", default=[])
        try:
            import_gym_packages(early.parse_known_args(args_in)[0].gym_packages)
        except ValueError as exc:
            parser.error(f"{chosen}: {exc}")
    for name, (module_name, help_text) in SUBCOMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        if name in TAKES_ENV:
            p.add_argument("--gym-packages", nargs="+", default=[], metavar="MODULE", help=GYM_PACKAGES_HELP)
        if name == chosen:
            module = importlib.import_module(module_name)
            module.add_arguments(p)
            p.set_defaults(_run=module.run)
    args = parser.parse_args(args_in)
    use_compilation_cache()
    try:
        return int(args._run(args) or 0)
    except ValueError as exc:  # a value argparse accepted but the command cannot use: a usage error
        parser.error(f"{args.command}: {exc}")


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
