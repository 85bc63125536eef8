"""The classical baselines of the comparison, and how their settings are chosen: on validation
episodes only (seeds from 5 000), never on the test episodes (seeds from 10 000).

``CLASSICAL`` names each baseline with its class and its grid of settings; [`tune`][vnhc_gym.baselines.tune] evaluates
every setting on validation episodes and keeps the one with the highest mean ``score`` (the return
over the fixed horizon per step, a terminated episode's remaining steps counting 0:
`vnhc_gym.evaluation.metrics`), so a setting that fails some episodes cannot win on how well it
held the constraint before failing.

``REFERENCE`` holds the headroom reference ``oracle``, tuned the same way: the sampled-data law on
the environment's true state and parameters (`vnhc_gym.baselines.oracle`).  It is not a
controller one could field, and never a cell's best classical baseline; it says how far that
baseline is from what the law attains with perfect information.
"""

from __future__ import annotations

import itertools
from typing import Any

from vnhc_gym.baselines.adaptive import AdaptiveController
from vnhc_gym.baselines.geometric import DEFAULT_GAIN, GeometricController
from vnhc_gym.baselines.mpc import MPCController
from vnhc_gym.baselines.observer import ObserverController
from vnhc_gym.baselines.oracle import OracleController

__all__ = ["CLASSICAL", "REFERENCE", "SELECTION_METRIC", "evaluate_classical", "make_classical", "selection_score",
           "tune"]

#: The metric that settings (and the best classical baseline of a cell) are chosen on: its mean over
#: the validation episodes, higher is better.
SELECTION_METRIC = "score"

#: Baseline name -> (policy class, grid of keyword arguments).  ``law`` is the fixed reference
#: (k = 5); the others are tuned per (environment, scenario).
CLASSICAL: dict[str, tuple[type, dict[str, list[Any]]]] = {
    "law": (GeometricController, {"gain": [DEFAULT_GAIN]}),
    "tuned_law": (GeometricController, {"gain": [1.0, 2.0, 3.0, 5.0, 8.0, 12.0, 20.0]}),
    "observer": (ObserverController, {"gain": [2.0, 5.0, 10.0], "alpha": [0.3, 0.1, 0.03, 0.01, 0.003]}),
    "adaptive": (AdaptiveController, {"gain": [2.0, 5.0, 10.0]}),
    "mpc": (MPCController, {"gain": [2.0, 5.0, 10.0, 20.0], "horizon": [8]}),
}
#: The headroom reference, in the same form (the gain of exp(-k dt) per control period).
REFERENCE: dict[str, tuple[type, dict[str, list[Any]]]] = {
    "oracle": (OracleController, {"gain": [2.0, 5.0, 10.0, 20.0, 40.0, 80.0, 160.0]}),
}


def make_classical(name: str, env: Any, **kwargs: Any) -> Any:
    """The baseline ``name`` of ``CLASSICAL`` (or the ``REFERENCE``) on ``env`` with the given settings."""
    table = {**CLASSICAL, **REFERENCE}
    if name not in table:
        raise ValueError(f"unknown classical baseline {name!r}; valid: {sorted(table)}")
    cls, _ = table[name]
    policy = cls(env, **kwargs)
    policy.name = name
    return policy


def evaluate_classical(name: str, settings: dict[str, Any], env_id: str, scenario: str, n_episodes: int, seed: int,
                       built: list[Any] | None = None, **env_kwargs: Any) -> Any:
    """[`evaluate`][vnhc_gym.evaluation.evaluate] of the baseline ``name`` with ``settings`` (built on the
    evaluation's own environment); ``built`` collects the policies built (to read their statistics,
    such as the planning baseline's solve time)."""
    from vnhc_gym.evaluation import evaluate

    def factory(env: Any) -> Any:
        policy = make_classical(name, env, **settings)
        if built is not None:
            built.append(policy)
        return policy

    res = evaluate(factory, env_id, scenario, n_episodes=n_episodes, seed=seed, **env_kwargs)
    res.policy = name
    return res


def selection_score(result: Any) -> float:
    """What settings and checkpoints are chosen on: the mean ``score`` of an evaluation's episodes."""
    return float(result.metrics[SELECTION_METRIC].mean())


def tune(name: str, env_id: str, scenario: str, n_episodes: int = 10, seed: int | None = None,
         **env_kwargs: Any) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """The best settings of baseline ``name`` (of ``CLASSICAL`` or ``REFERENCE``) in one cell, and every
    setting's validation score.

    Returns ``(best_kwargs, table)``; ``table`` rows hold the settings, ``score`` (the mean score over
    the validation episodes, [`selection_score`][vnhc_gym.baselines.tuning.selection_score]) and
    ``success`` (the fraction of them that reached the time limit).  The highest score wins; the
    first setting of the grid wins a tie.
    """
    from vnhc_gym.evaluation import TEST_SEED, VALIDATION_SEED

    first = VALIDATION_SEED if seed is None else seed
    if first + n_episodes > TEST_SEED:
        raise ValueError(f"tuning episodes (seeds {first}..{first + n_episodes - 1}) must stay below the test seeds "
                         f"({TEST_SEED} and up); pass a smaller seed or n_episodes")
    table_of = {**CLASSICAL, **REFERENCE}
    if name not in table_of:
        raise ValueError(f"unknown classical baseline {name!r}; valid: {sorted(table_of)}")
    _, grid = table_of[name]
    keys = sorted(grid)
    table = []
    for values in itertools.product(*(grid[k] for k in keys)):
        kwargs = dict(zip(keys, values, strict=True))
        res = evaluate_classical(name, kwargs, env_id, scenario, n_episodes, first, **env_kwargs)
        table.append({**kwargs, "score": selection_score(res), "success": float(res.metrics["success"].mean())})
    best = max(table, key=lambda row: row["score"])
    return {k: best[k] for k in keys}, table
